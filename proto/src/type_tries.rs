//! An episode's interactions by the type of the object tried, the last
//! section of the stats message ([`crate::EpisodeStats::tries`]): which
//! objects the policy tries, and so which objects carry the labels (issue
//! 65's label statistics; `learner summary` tabulates them per span).
//!
//! Layout: the number of records u32 (at most [`MAX_TYPE_TRIES`]), reserved
//! u32 (0; it also keeps every stats message longer than a join, whose
//! exact length the transport lets strangers send), then per record, in
//! increasing (affordance code, type name) order: the affordance's code
//! u32, attempts u32, successes u32, objects u32, the name's length in
//! bytes u32, then the name (ASCII letters, digits and `_`, 1 to
//! [`MAX_TYPE_NAME`] bytes) padded with zeros to four bytes.

use crate::arrays::read_u32;
use crate::task::Affordance;
use crate::ProtoError;

/// Bytes of the section before its records: count and reserved.
const SECTION_HEAD_LEN: usize = 8;
/// Bytes of a record before its name.
const RECORD_HEAD_LEN: usize = 20;

/// Most records one episode's metrics may carry.
pub const MAX_TYPE_TRIES: usize = 128;
/// Longest object type name a record may carry, in bytes.
pub const MAX_TYPE_NAME: usize = 64;

/// One object type's interactions of one affordance in an episode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TypeTries {
    /// The affordance tried.
    pub affordance: Affordance,
    /// The simulator's type of the objects tried (`Drawer`, `KeyChain`).
    pub object_type: String,
    /// Attempts on objects of this type.
    pub attempts: u32,
    /// Of those, the successful ones.
    pub successes: u32,
    /// Distinct objects of this type tried (at most `attempts`).
    pub objects: u32,
}

impl TypeTries {
    fn name_len_padded(&self) -> usize {
        self.object_type.len().div_ceil(4) * 4
    }

    /// Sort key of the records on the wire.
    fn key(&self) -> (u32, &str) {
        (self.affordance.code(), &self.object_type)
    }
}

/// Bytes the section takes with `tries` in it.
pub(crate) const fn section_len(tries: &[TypeTries]) -> usize {
    let mut len = SECTION_HEAD_LEN;
    let mut i = 0;
    while i < tries.len() {
        len += RECORD_HEAD_LEN + tries[i].object_type.len().div_ceil(4) * 4;
        i += 1;
    }
    len
}

/// `name` as a record may carry it: other characters become `_`, cut to
/// [`MAX_TYPE_NAME`] bytes, `unknown` if empty.
fn wire_type_name(name: &str) -> String {
    let cleaned: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .take(MAX_TYPE_NAME)
        .collect();
    if cleaned.is_empty() {
        "unknown".into()
    } else {
        cleaned
    }
}

/// Whether `name` is a type name a record may carry.
fn valid_type_name(name: &[u8]) -> bool {
    (1..=MAX_TYPE_NAME).contains(&name.len())
        && name.iter().all(|b| b.is_ascii_alphanumeric() || *b == b'_')
}

/// `kept` and `more` as one list the wire can carry (see
/// [`crate::EpisodeStats::with_tries`]).
pub(crate) fn merged(
    mut kept: Vec<TypeTries>,
    more: impl IntoIterator<Item = TypeTries>,
) -> Vec<TypeTries> {
    kept.extend(more.into_iter().filter(|t| t.attempts > 0).map(|mut t| {
        t.object_type = wire_type_name(&t.object_type);
        t.successes = t.successes.min(t.attempts);
        t.objects = t.objects.clamp(1, t.attempts);
        t
    }));
    kept.sort_by(|a, b| a.key().cmp(&b.key()));
    kept.dedup_by(|later, earlier| {
        let same = later.key() == earlier.key();
        if same {
            earlier.attempts += later.attempts;
            earlier.successes += later.successes;
            earlier.objects += later.objects;
        }
        same
    });
    keep_most_tried(&mut kept, MAX_TYPE_TRIES);
    kept
}

/// Keeps the `n` records with the most attempts (the first on ties), in
/// their order.
pub(crate) fn keep_most_tried(tries: &mut Vec<TypeTries>, n: usize) {
    if tries.len() <= n {
        return;
    }
    let mut order: Vec<usize> = (0..tries.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(tries[i].attempts), i));
    let mut keep = vec![false; tries.len()];
    for &i in &order[..n] {
        keep[i] = true;
    }
    let mut index = 0;
    tries.retain(|_| {
        index += 1;
        keep[index - 1]
    });
}

/// Reads the section at `at` of `payload`, checking every record; returns
/// the records and where the section ends.
pub(crate) fn read_section(
    payload: &[u8],
    at: usize,
) -> Result<(Vec<TypeTries>, usize), ProtoError> {
    let truncated = |needed: usize| ProtoError::Truncated {
        what: "stats' tries by object type",
        needed,
        got: payload.len(),
    };
    if payload.len() < at + SECTION_HEAD_LEN {
        return Err(truncated(at + SECTION_HEAD_LEN));
    }
    let out_of_range = |field, value: u32, allowed| ProtoError::OutOfRange {
        field,
        value: value.into(),
        allowed,
    };
    let count = read_u32(payload, at);
    if count as usize > MAX_TYPE_TRIES {
        return Err(out_of_range(
            "tries by object type",
            count,
            "at most MAX_TYPE_TRIES records",
        ));
    }
    let reserved = read_u32(payload, at + 4);
    if reserved != 0 {
        return Err(out_of_range("tries' reserved", reserved, "0"));
    }
    let mut tries: Vec<TypeTries> = Vec::with_capacity(count as usize);
    let mut at = at + SECTION_HEAD_LEN;
    for _ in 0..count {
        if payload.len() < at + RECORD_HEAD_LEN {
            return Err(truncated(at + RECORD_HEAD_LEN));
        }
        let code = read_u32(payload, at);
        let affordance = Affordance::from_code(code).ok_or(out_of_range(
            "tries' affordance code",
            code,
            "a known affordance",
        ))?;
        let [attempts, successes, objects, name_len] =
            [4, 8, 12, 16].map(|offset| read_u32(payload, at + offset));
        if successes > attempts || objects == 0 || objects > attempts {
            return Err(out_of_range(
                "tries' counts",
                attempts,
                "successes and objects at most the attempts, at least one object",
            ));
        }
        let name_at = at + RECORD_HEAD_LEN;
        let padded = (name_len as usize).div_ceil(4) * 4;
        if name_len as usize > MAX_TYPE_NAME || payload.len() < name_at + padded {
            return Err(out_of_range(
                "tries' type name length",
                name_len,
                "1 to MAX_TYPE_NAME bytes, within the message",
            ));
        }
        let name = &payload[name_at..name_at + name_len as usize];
        let padding = &payload[name_at + name_len as usize..name_at + padded];
        if !valid_type_name(name) || padding.iter().any(|&b| b != 0) {
            return Err(out_of_range(
                "tries' type name",
                name_len,
                "ASCII letters, digits and _, padded with zeros",
            ));
        }
        let record = TypeTries {
            affordance,
            object_type: String::from_utf8_lossy(name).into_owned(),
            attempts,
            successes,
            objects,
        };
        if tries.last().is_some_and(|p| p.key() >= record.key()) {
            return Err(out_of_range(
                "tries' order",
                code,
                "records in increasing (affordance, type name) order",
            ));
        }
        tries.push(record);
        at = name_at + padded;
    }
    Ok((tries, at))
}

/// Writes the section with `tries` (as [`merged`] leaves them) at the
/// start of `out`, which holds at least [`section_len`] bytes.
pub(crate) fn write_section(tries: &[TypeTries], out: &mut [u8]) {
    out[0..4].copy_from_slice(&(tries.len() as u32).to_le_bytes());
    out[4..8].copy_from_slice(&0u32.to_le_bytes());
    let mut at = SECTION_HEAD_LEN;
    for record in tries {
        let name = record.object_type.as_bytes();
        let head = [
            record.affordance.code(),
            record.attempts,
            record.successes,
            record.objects,
            name.len() as u32,
        ];
        for (i, word) in head.into_iter().enumerate() {
            out[at + 4 * i..at + 4 * i + 4].copy_from_slice(&word.to_le_bytes());
        }
        let name_at = at + RECORD_HEAD_LEN;
        let end = name_at + record.name_len_padded();
        out[name_at..name_at + name.len()].copy_from_slice(name);
        out[name_at + name.len()..end].fill(0);
        at = end;
    }
}
