//! Little-endian array views over unaligned bytes.
//!
//! Payload arrays are read in place, without assuming the buffer is aligned,
//! so a view is valid over any byte slice whose length was checked.

/// A read-only view of little-endian `f32`s.
#[derive(Debug, Clone, Copy)]
pub struct F32Array<'a>(&'a [u8]);

/// A read-only view of little-endian `u32`s.
#[derive(Debug, Clone, Copy)]
pub struct U32Array<'a>(&'a [u8]);

macro_rules! array_view {
    ($name:ident, $t:ty) => {
        impl<'a> $name<'a> {
            /// Wraps bytes whose length is a multiple of the element size.
            pub(crate) fn new(bytes: &'a [u8]) -> Self {
                debug_assert_eq!(bytes.len() % 4, 0);
                Self(bytes)
            }
            /// Number of elements.
            pub fn len(&self) -> usize {
                self.0.len() / 4
            }
            /// True when the view holds no elements.
            pub fn is_empty(&self) -> bool {
                self.0.is_empty()
            }
            /// Element `i`, or `None` past the end.
            pub fn get(&self, i: usize) -> Option<$t> {
                let b = self.0.get(i * 4..i * 4 + 4)?;
                Some(<$t>::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            /// All elements in order.
            pub fn iter(&self) -> impl Iterator<Item = $t> + 'a {
                self.0
                    .chunks_exact(4)
                    .map(|b| <$t>::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            /// Copies the elements out.
            pub fn to_vec(&self) -> Vec<$t> {
                self.iter().collect()
            }
            /// The raw little-endian bytes.
            pub fn as_bytes(&self) -> &'a [u8] {
                self.0
            }
        }
    };
}
array_view!(F32Array, f32);
array_view!(U32Array, u32);

/// Appends values as little-endian bytes.
pub(crate) fn put_f32s(out: &mut [u8], values: &[f32]) {
    for (dst, v) in out.chunks_exact_mut(4).zip(values) {
        dst.copy_from_slice(&v.to_le_bytes());
    }
}

/// Appends values as little-endian bytes.
pub(crate) fn put_u32s(out: &mut [u8], values: &[u32]) {
    for (dst, v) in out.chunks_exact_mut(4).zip(values) {
        dst.copy_from_slice(&v.to_le_bytes());
    }
}

/// A cursor that hands out consecutive sub-slices of a checked buffer.
pub(crate) struct Splitter<'a> {
    rest: &'a [u8],
}

impl<'a> Splitter<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self { rest: bytes }
    }
    /// Takes `n` bytes; callers check the total length first, so this cannot fail
    /// on a validated layout, but it still returns `None` rather than panic.
    pub(crate) fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if n > self.rest.len() {
            return None;
        }
        let (head, tail) = self.rest.split_at(n);
        self.rest = tail;
        Some(head)
    }
}

/// Mutable counterpart of [`Splitter`] for writers.
pub(crate) struct SplitterMut<'a> {
    rest: &'a mut [u8],
}

impl<'a> SplitterMut<'a> {
    pub(crate) fn new(bytes: &'a mut [u8]) -> Self {
        Self { rest: bytes }
    }
    /// Takes `n` bytes. Writers size the buffer with `encoded_len` first.
    pub(crate) fn take(&mut self, n: usize) -> &'a mut [u8] {
        let rest = std::mem::take(&mut self.rest);
        let (head, tail) = rest.split_at_mut(n);
        self.rest = tail;
        head
    }
}

/// Reads a little-endian `u32` at `offset` of a buffer already checked to be long enough.
pub(crate) fn read_u32(b: &[u8], offset: usize) -> u32 {
    u32::from_le_bytes([b[offset], b[offset + 1], b[offset + 2], b[offset + 3]])
}

/// Reads a little-endian `u64` at `offset` of a buffer already checked to be long enough.
pub(crate) fn read_u64(b: &[u8], offset: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[offset..offset + 8]);
    u64::from_le_bytes(a)
}

/// Checks that every float is finite and, when `range` is given, inside it.
pub(crate) fn check_floats(
    field: &'static str,
    values: F32Array<'_>,
    range: Option<(f32, f32)>,
    extra: &'static str,
) -> Result<(), crate::ProtoError> {
    for (index, value) in values.iter().enumerate() {
        let ok = value.is_finite() && range.is_none_or(|(lo, hi)| (lo..=hi).contains(&value));
        if !ok {
            return Err(crate::ProtoError::BadFloat {
                field,
                index,
                value,
                extra,
            });
        }
    }
    Ok(())
}
