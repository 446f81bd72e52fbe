//! What every payload layout shares: the trait that writes one after a
//! header, and the checks its parser uses on untrusted sizes. Kept apart
//! from the message codec so payloads and the codec do not import each other.

use crate::{MessageKind, ProtoError};

/// A payload that can be written after a header.
pub trait Payload {
    /// The kind written into the header.
    const KIND: MessageKind;
    /// Exact number of payload bytes [`Payload::write_payload`] writes.
    fn payload_len(&self) -> usize;
    /// Writes exactly [`Payload::payload_len`] bytes into `out`.
    fn write_payload(&self, out: &mut [u8]);
}

/// Returns an error unless `len` equals `expected` (both as declared by a layout).
pub(crate) fn check_layout(
    what: &'static str,
    expected: u64,
    len: usize,
) -> Result<(), ProtoError> {
    if expected != len as u64 {
        return Err(ProtoError::LayoutMismatch {
            what,
            expected,
            actual: len as u64,
        });
    }
    Ok(())
}

/// Returns an error unless `lo <= value <= hi`.
pub(crate) fn check_range(
    field: &'static str,
    value: u64,
    lo: u64,
    hi: u64,
    allowed: &'static str,
) -> Result<(), ProtoError> {
    if value < lo || value > hi {
        return Err(ProtoError::OutOfRange {
            field,
            value,
            allowed,
        });
    }
    Ok(())
}

/// Sums sizes with overflow detection; an overflow is reported as an impossible layout.
pub(crate) fn checked_total(
    what: &'static str,
    parts: &[(u64, u64)],
    actual: usize,
) -> Result<u64, ProtoError> {
    let mut total: u64 = 0;
    for &(count, size) in parts {
        let bytes = count.checked_mul(size);
        total = match bytes.and_then(|b| total.checked_add(b)) {
            Some(t) => t,
            None => {
                return Err(ProtoError::LayoutMismatch {
                    what,
                    expected: u64::MAX,
                    actual: actual as u64,
                })
            }
        };
    }
    Ok(total)
}
