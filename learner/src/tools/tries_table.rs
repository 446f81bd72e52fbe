//! `learner summary`'s second table: interactions by the type of the object
//! tried, per span of steps, read from the `tries` of the history's episode
//! records. Which objects the policy tries is which objects carry labels
//! (docs/ladder.md): a network that rates drawers pickable, say, was either
//! never shown a drawer's failure or shown too few.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::{json, Value};

/// An affordance's name and an object type, as the history names them.
pub type TriedType = (String, String);

/// Attempts and successes by (affordance, object type).
pub type Tries = BTreeMap<TriedType, (u64, u64)>;

/// Adds the `tries` of one episode record of the history to `into`
/// (records written before episodes reported them add nothing).
pub(crate) fn add_episode(into: &mut Tries, record: &Value) {
    for tried in record["tries"].as_array().into_iter().flatten() {
        let (Some(affordance), Some(object_type)) =
            (tried["affordance"].as_str(), tried["type"].as_str())
        else {
            continue;
        };
        let key = (affordance.to_string(), object_type.to_string());
        let sums = into.entry(key).or_default();
        sums.0 += tried["attempts"].as_u64().unwrap_or(0);
        sums.1 += tried["successes"].as_u64().unwrap_or(0);
    }
}

/// `spans` added up (repeats' spans: all runs together).
pub(crate) fn total<'a>(spans: impl IntoIterator<Item = &'a Tries>) -> Tries {
    let mut all = Tries::new();
    for span in spans {
        for (key, &(attempts, successes)) in span {
            let sums = all.entry(key.clone()).or_default();
            sums.0 += attempts;
            sums.1 += successes;
        }
    }
    all
}

/// Every (affordance, object type) some span tried: by affordance, then the
/// most attempts over all spans first, then by name.
pub fn tried_types<'a>(spans: impl IntoIterator<Item = &'a Tries>) -> Vec<TriedType> {
    let mut keys: Vec<(TriedType, u64)> = total(spans)
        .into_iter()
        .map(|(key, (attempts, _))| (key, attempts))
        .collect();
    keys.sort_by(|(a, na), (b, nb)| a.0.cmp(&b.0).then(nb.cmp(na)).then(a.1.cmp(&b.1)));
    keys.into_iter().map(|(key, _)| key).collect()
}

/// The table in Markdown after a blank line, when any span tried anything:
/// one row per (affordance, object type), one column per span (`spans`:
/// its heading and its tries) and one for all, `attempts (successes)`.
pub(crate) fn markdown(out: &mut String, spans: &[(String, &Tries)], repeats: bool) {
    let types = tried_types(spans.iter().map(|(_, tries)| *tries));
    if types.is_empty() {
        return;
    }
    let together = if repeats { ", all runs together" } else { "" };
    let _ = write!(
        out,
        "\nInteractions by the type of the object tried: attempts (successes){together}\n\n| affordance | object type |"
    );
    for (heading, _) in spans {
        let _ = write!(out, " {heading} |");
    }
    out.push_str(" all |\n|---|---|");
    out.push_str(&"---|".repeat(spans.len() + 1));
    out.push('\n');
    for key in &types {
        let _ = write!(out, "| {} | {} |", key.0, key.1);
        let mut all = (0, 0);
        for (_, tries) in spans {
            let (attempts, successes) = tries.get(key).copied().unwrap_or_default();
            all = (all.0 + attempts, all.1 + successes);
            let _ = write!(out, " {attempts} ({successes}) |");
        }
        let _ = writeln!(out, " {} ({}) |", all.0, all.1);
    }
}

/// `{affordance: {object type: [attempts, successes]}}`.
pub(crate) fn json(tries: &Tries) -> Value {
    let mut by_affordance = serde_json::Map::new();
    for ((affordance, object_type), &(attempts, successes)) in tries {
        let types = by_affordance
            .entry(affordance.clone())
            .or_insert_with(|| json!({}));
        types[object_type] = json!([attempts, successes]);
    }
    Value::Object(by_affordance)
}
