//! Table 2 by object type: for each type of object tried, how many were
//! tried, the share that afforded each affordance, and the network's mean
//! prediction for them. It shows which kinds of object the network gets
//! wrong (a sofa rated as pickable as a pillow), which Table 2's single
//! row hides (docs/ladder.md).

use std::collections::BTreeMap;
use std::fmt::Write as _;

/// One object type's trials, per affordance in plane order.
#[derive(Debug, Clone, PartialEq)]
pub struct TypeRow {
    /// The object type (`Sofa`).
    pub object_type: String,
    /// Objects of this type in Table 2.
    pub objects: usize,
    /// Per affordance, the share of them that afforded it.
    pub afforded: Vec<f32>,
    /// Per affordance, the mean of their predicted probabilities.
    pub predicted: Vec<f32>,
}

/// One object's trial as the table needs it: its type, and per affordance
/// its predicted probability and whether it afforded it.
pub type Tried<'a> = (&'a str, &'a [f32], &'a [bool]);

/// One object's predictions and outcomes, per affordance.
type Outcome<'a> = (&'a [f32], &'a [bool]);

/// The rows of `trials` by object type, most tried first (then by name).
pub fn by_object_type<'a>(trials: impl IntoIterator<Item = Tried<'a>>) -> Vec<TypeRow> {
    let mut groups: BTreeMap<&str, Vec<Outcome>> = BTreeMap::new();
    for (object_type, predicted, succeeded) in trials {
        groups
            .entry(object_type)
            .or_default()
            .push((predicted, succeeded));
    }
    let mut rows: Vec<TypeRow> = groups
        .into_iter()
        .map(|(object_type, group)| {
            let n = group.len() as f32;
            let planes = group.iter().map(|(_, s)| s.len()).min().unwrap_or(0);
            let afforded = (0..planes)
                .map(|k| group.iter().filter(|(_, s)| s[k]).count() as f32 / n)
                .collect();
            let predicted = (0..planes)
                .map(|k| {
                    group
                        .iter()
                        .map(|(p, _)| p.get(k).copied().unwrap_or(0.0))
                        .sum::<f32>()
                        / n
                })
                .collect();
            TypeRow {
                object_type: object_type.to_owned(),
                objects: group.len(),
                afforded,
                predicted,
            }
        })
        .collect();
    rows.sort_by(|a, b| {
        b.objects
            .cmp(&a.objects)
            .then_with(|| a.object_type.cmp(&b.object_type))
    });
    rows
}

/// The rows as a Markdown table with one afforded / predicted column pair
/// per affordance of `affordances`.
pub fn markdown(rows: &[TypeRow], affordances: &[String]) -> String {
    let mut out = String::from("| object type | objects |");
    for a in affordances {
        let _ = write!(out, " {a}: afforded | {a}: mean predicted |");
    }
    out.push_str("\n|---|---|");
    out.push_str(&"---|---|".repeat(affordances.len()));
    out.push('\n');
    for row in rows {
        let _ = write!(out, "| {} | {} |", row.object_type, row.objects);
        for (afforded, predicted) in row.afforded.iter().zip(&row.predicted) {
            let _ = write!(out, " {afforded:.2} | {predicted:.2} |");
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    type Trial = (&'static str, [f32; 1], [bool; 1]);

    fn trial(object_type: &'static str, predicted: f32, succeeded: bool) -> Trial {
        (object_type, [predicted], [succeeded])
    }

    #[test]
    fn types_are_counted_averaged_and_listed_most_tried_first() {
        let trials = [
            trial("Pillow", 0.8, true),
            trial("Sofa", 0.6, false),
            trial("Sofa", 0.4, false),
            trial("Box", 0.9, true),
            trial("Box", 0.5, false),
        ];
        let rows = by_object_type(trials.iter().map(|(t, p, s)| (*t, &p[..], &s[..])));
        let names: Vec<&str> = rows.iter().map(|r| r.object_type.as_str()).collect();
        assert_eq!(names, ["Box", "Sofa", "Pillow"]);
        assert_eq!(rows[0].objects, 2);
        assert!((rows[0].afforded[0] - 0.5).abs() < 1e-6);
        assert!((rows[0].predicted[0] - 0.7).abs() < 1e-6);
        assert!((rows[1].afforded[0]).abs() < 1e-6 && (rows[1].predicted[0] - 0.5).abs() < 1e-6);
        let table = markdown(&rows, &["pick_up".to_owned()]);
        assert!(table.contains("| Sofa | 2 | 0.00 | 0.50 |"), "{table}");
        assert_eq!(table.lines().count(), 2 + 3);
    }
}
