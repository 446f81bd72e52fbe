//! Interaction outcomes and confidence labels stored on map objects.

/// What the robot can try on an object: the wire contract's enum, so the
/// map, the actor and the learner share one definition.
pub use proto::Affordance;

/// The result of one interaction attempt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The interaction succeeded.
    Success,
    /// The interaction was tried and failed.
    Failure,
}

/// Outcomes of one affordance on one object.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AffordanceRecord {
    /// Successful attempts.
    pub successes: u32,
    /// Failed attempts.
    pub failures: u32,
    /// The most recent attempt's outcome.
    pub last: Option<Outcome>,
    /// A label from annotation by confidence, for objects never tried.
    pub confidence_label: Option<bool>,
}

/// All affordance records of one object.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjectLabels {
    records: [AffordanceRecord; Affordance::ALL.len()],
}

impl ObjectLabels {
    /// Records an attempt.
    pub fn record(&mut self, affordance: Affordance, outcome: Outcome) {
        let r = &mut self.records[affordance as usize];
        match outcome {
            Outcome::Success => r.successes += 1,
            Outcome::Failure => r.failures += 1,
        }
        r.last = Some(outcome);
    }

    /// Adds another record of the same object (a copy merged into it): the
    /// attempts add up; this record's last outcome and confidence label
    /// stay, the other's fill in where this has none.
    pub fn absorb(&mut self, other: &ObjectLabels) {
        for (mine, theirs) in self.records.iter_mut().zip(&other.records) {
            mine.successes += theirs.successes;
            mine.failures += theirs.failures;
            mine.last = mine.last.or(theirs.last);
            mine.confidence_label = mine.confidence_label.or(theirs.confidence_label);
        }
    }

    /// Sets (or clears) the label from annotation by confidence.
    pub fn set_confidence_label(&mut self, affordance: Affordance, label: Option<bool>) {
        self.records[affordance as usize].confidence_label = label;
    }

    /// The record of one affordance.
    pub fn record_of(&self, affordance: Affordance) -> &AffordanceRecord {
        &self.records[affordance as usize]
    }

    /// True if the object was ever tried with this affordance.
    pub fn interacted(&self, affordance: Affordance) -> bool {
        let r = self.record_of(affordance);
        r.successes + r.failures > 0
    }

    /// The object's label: interaction outcomes win (one success makes it
    /// positive: the robot *can* do it), else the confidence label, else none.
    pub fn label(&self, affordance: Affordance) -> Option<bool> {
        let r = self.record_of(affordance);
        if r.successes > 0 {
            Some(true)
        } else if r.failures > 0 {
            Some(false)
        } else {
            r.confidence_label
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interaction_outcomes_win_over_confidence() {
        let mut l = ObjectLabels::default();
        assert_eq!(l.label(Affordance::Push), None);
        l.set_confidence_label(Affordance::Push, Some(false));
        assert_eq!(l.label(Affordance::Push), Some(false));
        l.record(Affordance::Push, Outcome::Failure);
        l.record(Affordance::Push, Outcome::Success);
        assert_eq!(l.label(Affordance::Push), Some(true));
        assert_eq!(l.record_of(Affordance::Push).last, Some(Outcome::Success));
        assert!(!l.interacted(Affordance::PickUp));
    }
}
