//! Rollout chunks: `T` consecutive environment steps of one actor.
//!
//! Layout after the message header (all little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 8 | episode_id u64 |
//! | 4 | first_step u32 (index of the chunk's first step within its episode) |
//! | 4 | n_steps u32 |
//! | 4 | obs_elems u32 (observation elements per step) |
//! | 4 | obs_dtype u32 ([`ObsDtype`]) |
//! | 4 | n_actions u32 |
//! | 4 | bootstrap_value f32 (critic value of the state after the last step) |
//! | 4 | hidden_len u32 (recurrent state size; 0 for a policy without memory) |
//! | 4·hidden_len | start_hidden f32 (the policy's recurrent state before the first step) |
//! | 4·T | actions u32 |
//! | 4·T | log_probs f32 (behaviour policy) |
//! | 4·T | values f32 |
//! | 4·T | rewards f32 |
//! | T·obs_elems·size | observations |
//! | T·n_actions | action masks, one byte per action (1 = allowed) |
//! | T | dones u8 (1 = the episode ended after this step) |

use crate::arrays::{
    check_floats, put_f32s, put_u32s, read_u32, read_u64, F32Array, Splitter, SplitterMut, U32Array,
};
use crate::payload::{check_layout, check_range, checked_total, Payload};
use crate::{MessageKind, ProtoError};

const SUB_HEADER_LEN: usize = 36;
/// Most steps one chunk may hold.
pub const MAX_STEPS: u32 = 4096;
/// Most actions an action space may have.
pub const MAX_ACTIONS: u32 = 256;
/// Most observation elements per step (16 channels of 1024 × 1024).
pub const MAX_OBS_ELEMS: u32 = 1 << 24;
/// Largest recurrent state a chunk may carry.
pub const MAX_HIDDEN: u32 = 1 << 16;

/// Element type of the observation array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ObsDtype {
    /// Bytes, e.g. quantised images.
    U8 = 0,
    /// Little-endian `f32`, checked finite on receipt.
    F32 = 1,
}

impl ObsDtype {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            ObsDtype::U8 => 1,
            ObsDtype::F32 => 4,
        }
    }
    fn from_wire(v: u32) -> Result<Self, ProtoError> {
        match v {
            0 => Ok(Self::U8),
            1 => Ok(Self::F32),
            other => Err(ProtoError::OutOfRange {
                field: "obs_dtype",
                value: other.into(),
                allowed: "0 (u8) or 1 (f32)",
            }),
        }
    }
}

/// An owned rollout chunk, as an actor builds it.
#[derive(Debug, Clone, PartialEq)]
pub struct RolloutChunk {
    /// Episode this chunk belongs to (unique per actor).
    pub episode_id: u64,
    /// Index of the first step within the episode.
    pub first_step: u32,
    /// Size of the action space.
    pub n_actions: u32,
    /// Element type of `obs`.
    pub obs_dtype: ObsDtype,
    /// Observation elements per step.
    pub obs_elems: u32,
    /// Raw observation bytes, `n_steps · obs_elems · obs_dtype.size()` long.
    pub obs: Vec<u8>,
    /// Action taken at each step.
    pub actions: Vec<u32>,
    /// Allowed actions per step, `n_steps · n_actions` bytes of 0 / 1.
    pub masks: Vec<u8>,
    /// Log-probability of each action under the behaviour policy.
    pub log_probs: Vec<f32>,
    /// Critic value of each step's state.
    pub values: Vec<f32>,
    /// Reward received after each step.
    pub rewards: Vec<f32>,
    /// 1 where the episode ended after the step.
    pub dones: Vec<u8>,
    /// Critic value of the state after the last step (0 if it ended the episode).
    pub bootstrap_value: f32,
    /// The policy's recurrent state before the first step (zeros at an
    /// episode's start; empty for a policy without memory), so the learner
    /// can replay the chunk as a sequence.
    pub start_hidden: Vec<f32>,
}

impl RolloutChunk {
    /// Number of steps.
    pub fn n_steps(&self) -> usize {
        self.actions.len()
    }

    /// A valid chunk of `steps` steps (one action, byte observations)
    /// whose whole message is about `message_len` bytes: what transport
    /// benchmarks send.
    pub fn filler(message_len: usize, steps: usize) -> Self {
        let t = steps.max(1);
        let fixed = 32 + 16 * t + 2 * t; // sub-header, four arrays, masks, dones
        let obs_elems = message_len.saturating_sub(crate::HEADER_LEN + fixed).max(t) / t;
        RolloutChunk {
            episode_id: 1,
            first_step: 0,
            n_actions: 1,
            obs_dtype: ObsDtype::U8,
            obs_elems: obs_elems as u32,
            obs: (0..t * obs_elems).map(|i| i as u8).collect(),
            actions: vec![0; t],
            masks: vec![1; t],
            log_probs: vec![-0.5; t],
            values: vec![0.0; t],
            rewards: vec![0.0; t],
            dones: vec![0; t],
            bootstrap_value: 0.0,
            start_hidden: Vec::new(),
        }
    }
}

/// A value in 0..1 as a byte observation carries it: clamped, then the
/// nearest of 256 levels (halves up; NaN gives 0).
///
/// Rounds by truncating and comparing the remainder with one half, which
/// is exact for these values and equals `f32::round` on every `f32` in
/// 0..1 (checked on all of them once; the test below checks the halves'
/// neighbourhoods): `round` is a call into libm on x86-64's baseline,
/// and an actor converts every state value at least twice a step (426 k of
/// them at 128 px). The truncation is unchecked, since the clamped value
/// is known to fit: Rust's checked `as` (saturating, NaN to 0) kept a loop
/// of these from vectorising, about three times slower.
#[inline]
pub fn unit_to_byte(v: f32) -> u8 {
    // Not `clamp`, which keeps NaN: `max` returns 0 for it.
    #[allow(clippy::manual_clamp)]
    let scaled = v.max(0.0).min(1.0) * 255.0;
    // SAFETY: `scaled` is finite and within 0..=255, which an i32 holds.
    let whole = unsafe { scaled.to_int_unchecked::<i32>() };
    (whole + i32::from(scaled - whole as f32 >= 0.5)) as u8
}

/// A byte observation's value in 0..1.
#[inline]
pub fn byte_to_unit(b: u8) -> f32 {
    f32::from(b) / 255.0
}

/// [`byte_to_unit`] of every byte, by index: a load where a pass over
/// hundreds of thousands of bytes would divide each.
pub const BYTE_UNITS: [f32; 256] = {
    let mut units = [0.0; 256];
    let mut b = 0;
    while b < 256 {
        units[b] = b as f32 / 255.0;
        b += 1;
    }
    units
};

/// Converts `f32` observations to the wire's raw bytes.
pub fn obs_bytes_from_f32(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

impl Payload for RolloutChunk {
    const KIND: MessageKind = MessageKind::Rollout;

    fn payload_len(&self) -> usize {
        let t = self.n_steps();
        SUB_HEADER_LEN
            + 4 * self.start_hidden.len()
            + 16 * t
            + self.obs.len()
            + self.masks.len()
            + t
    }

    fn write_payload(&self, out: &mut [u8]) {
        let t = self.n_steps();
        let mut w = SplitterMut::new(out);
        let head = w.take(SUB_HEADER_LEN);
        head[0..8].copy_from_slice(&self.episode_id.to_le_bytes());
        head[8..12].copy_from_slice(&self.first_step.to_le_bytes());
        head[12..16].copy_from_slice(&(t as u32).to_le_bytes());
        head[16..20].copy_from_slice(&self.obs_elems.to_le_bytes());
        head[20..24].copy_from_slice(&(self.obs_dtype as u32).to_le_bytes());
        head[24..28].copy_from_slice(&self.n_actions.to_le_bytes());
        head[28..32].copy_from_slice(&self.bootstrap_value.to_le_bytes());
        head[32..36].copy_from_slice(&(self.start_hidden.len() as u32).to_le_bytes());
        put_f32s(w.take(4 * self.start_hidden.len()), &self.start_hidden);
        put_u32s(w.take(4 * t), &self.actions);
        put_f32s(w.take(4 * t), &self.log_probs);
        put_f32s(w.take(4 * t), &self.values);
        put_f32s(w.take(4 * t), &self.rewards);
        w.take(self.obs.len()).copy_from_slice(&self.obs);
        w.take(self.masks.len()).copy_from_slice(&self.masks);
        w.take(t).copy_from_slice(&self.dones);
    }
}

/// A validated, zero-copy view of a rollout chunk.
#[derive(Debug, Clone, Copy)]
pub struct RolloutView<'a> {
    /// Episode this chunk belongs to.
    pub episode_id: u64,
    /// Index of the first step within the episode.
    pub first_step: u32,
    /// Size of the action space.
    pub n_actions: u32,
    /// Element type of the observations.
    pub obs_dtype: ObsDtype,
    /// Observation elements per step.
    pub obs_elems: u32,
    /// Critic value after the last step.
    pub bootstrap_value: f32,
    /// Recurrent state before the first step (finite; empty without memory).
    pub start_hidden: F32Array<'a>,
    /// Actions, one per step, each `< n_actions` and allowed by its mask.
    pub actions: U32Array<'a>,
    /// Behaviour log-probabilities (finite, ≤ 0).
    pub log_probs: F32Array<'a>,
    /// Critic values (finite).
    pub values: F32Array<'a>,
    /// Rewards (finite).
    pub rewards: F32Array<'a>,
    obs: &'a [u8],
    masks: &'a [u8],
    /// 0 / 1 per step.
    pub dones: &'a [u8],
}

impl<'a> RolloutView<'a> {
    /// Number of steps.
    pub fn n_steps(&self) -> usize {
        self.dones.len()
    }

    /// Raw observation bytes of step `i`.
    pub fn obs(&self, i: usize) -> Option<&'a [u8]> {
        let size = self.obs_elems as usize * self.obs_dtype.size();
        self.obs.get(i * size..(i + 1) * size)
    }

    /// Action mask of step `i` (one byte per action, 1 = allowed).
    pub fn mask(&self, i: usize) -> Option<&'a [u8]> {
        let n = self.n_actions as usize;
        self.masks.get(i * n..(i + 1) * n)
    }

    /// Converts back to an owned chunk.
    pub fn to_owned(&self) -> RolloutChunk {
        RolloutChunk {
            episode_id: self.episode_id,
            first_step: self.first_step,
            n_actions: self.n_actions,
            obs_dtype: self.obs_dtype,
            obs_elems: self.obs_elems,
            obs: self.obs.to_vec(),
            actions: self.actions.to_vec(),
            masks: self.masks.to_vec(),
            log_probs: self.log_probs.to_vec(),
            values: self.values.to_vec(),
            rewards: self.rewards.to_vec(),
            dones: self.dones.to_vec(),
            bootstrap_value: self.bootstrap_value,
            start_hidden: self.start_hidden.to_vec(),
        }
    }

    pub(crate) fn parse(payload: &'a [u8]) -> Result<Self, ProtoError> {
        if payload.len() < SUB_HEADER_LEN {
            return Err(ProtoError::Truncated {
                what: "rollout sub-header",
                needed: SUB_HEADER_LEN,
                got: payload.len(),
            });
        }
        let episode_id = read_u64(payload, 0);
        let first_step = read_u32(payload, 8);
        let n_steps = read_u32(payload, 12);
        let obs_elems = read_u32(payload, 16);
        let obs_dtype = ObsDtype::from_wire(read_u32(payload, 20))?;
        let n_actions = read_u32(payload, 24);
        let bootstrap_value = f32::from_bits(read_u32(payload, 28));
        let hidden_len = read_u32(payload, 32);
        check_range(
            "hidden_len",
            hidden_len.into(),
            0,
            MAX_HIDDEN.into(),
            "0..=65536",
        )?;
        check_range("n_steps", n_steps.into(), 1, MAX_STEPS.into(), "1..=4096")?;
        check_range(
            "n_actions",
            n_actions.into(),
            1,
            MAX_ACTIONS.into(),
            "1..=256",
        )?;
        check_range(
            "obs_elems",
            obs_elems.into(),
            0,
            MAX_OBS_ELEMS.into(),
            "0..=2^24",
        )?;
        let t = u64::from(n_steps);
        let obs_len = checked_total(
            "rollout",
            &[(t * u64::from(obs_elems), obs_dtype.size() as u64)],
            payload.len(),
        )?;
        let expected = checked_total(
            "rollout",
            &[
                (SUB_HEADER_LEN as u64, 1),
                (hidden_len.into(), 4),
                (t, 16),
                (obs_len, 1),
                (t, n_actions.into()),
                (t, 1),
            ],
            payload.len(),
        )?;
        check_layout("rollout", expected, payload.len())?;

        let t = t as usize;
        let mut r = Splitter::new(&payload[SUB_HEADER_LEN..]);
        let truncated = || ProtoError::Truncated {
            what: "rollout arrays",
            needed: expected as usize,
            got: payload.len(),
        };
        let start_hidden = F32Array::new(r.take(4 * hidden_len as usize).ok_or_else(truncated)?);
        let actions = U32Array::new(r.take(4 * t).ok_or_else(truncated)?);
        let log_probs = F32Array::new(r.take(4 * t).ok_or_else(truncated)?);
        let values = F32Array::new(r.take(4 * t).ok_or_else(truncated)?);
        let rewards = F32Array::new(r.take(4 * t).ok_or_else(truncated)?);
        let obs = r.take(obs_len as usize).ok_or_else(truncated)?;
        let masks = r.take(t * n_actions as usize).ok_or_else(truncated)?;
        let dones = r.take(t).ok_or_else(truncated)?;

        if !bootstrap_value.is_finite() {
            return Err(ProtoError::BadFloat {
                field: "bootstrap_value",
                index: 0,
                value: bootstrap_value,
                extra: "",
            });
        }
        check_floats("log_probs", log_probs, Some((f32::MIN, 0.0)), ", <= 0")?;
        check_floats("values", values, None, "")?;
        check_floats("start_hidden", start_hidden, None, "")?;
        check_floats("rewards", rewards, None, "")?;
        if obs_dtype == ObsDtype::F32 {
            check_floats("obs", F32Array::new(obs), None, "")?;
        }
        if let Some(&bad) = masks.iter().find(|&&m| m > 1) {
            return Err(ProtoError::OutOfRange {
                field: "masks",
                value: bad.into(),
                allowed: "0 or 1",
            });
        }
        if let Some(&bad) = dones.iter().find(|&&d| d > 1) {
            return Err(ProtoError::OutOfRange {
                field: "dones",
                value: bad.into(),
                allowed: "0 or 1",
            });
        }
        let n = n_actions as usize;
        for (step, action) in actions.iter().enumerate() {
            if action >= n_actions {
                return Err(ProtoError::OutOfRange {
                    field: "actions",
                    value: action.into(),
                    allowed: "below n_actions",
                });
            }
            if masks[step * n + action as usize] == 0 {
                return Err(ProtoError::MaskedAction { step, action });
            }
        }
        Ok(Self {
            episode_id,
            first_step,
            n_actions,
            obs_dtype,
            obs_elems,
            bootstrap_value,
            start_hidden,
            actions,
            log_probs,
            values,
            rewards,
            obs,
            masks,
            dones,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_and_unit_values_round_trip_and_out_of_range_values_clamp() {
        for b in 0..=255u8 {
            assert_eq!(unit_to_byte(byte_to_unit(b)), b);
        }
        assert_eq!(unit_to_byte(-0.5), 0);
        assert_eq!(unit_to_byte(1.5), 255);
        assert_eq!(unit_to_byte(0.5), 128);
        assert_eq!(unit_to_byte(f32::NAN), 0);
        assert_eq!(unit_to_byte(f32::INFINITY), 255);
    }

    #[test]
    fn the_byte_table_holds_each_bytes_unit_value() {
        for b in 0..=255u8 {
            assert_eq!(
                BYTE_UNITS[usize::from(b)].to_bits(),
                byte_to_unit(b).to_bits()
            );
        }
    }

    #[test]
    fn unit_to_byte_rounds_as_f32_round_does_around_every_half_level() {
        let reference = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        for level in 0..=255u32 {
            // Every value whose scaled form lies within 64 ulps of a half
            // level, and of the level itself.
            for centre in [level as f32 + 0.5, level as f32] {
                let unit = (centre / 255.0).to_bits();
                for bits in unit.saturating_sub(64)..=unit + 64 {
                    let v = f32::from_bits(bits);
                    assert_eq!(unit_to_byte(v), reference(v), "{v:e}");
                }
            }
        }
        for (v, byte) in [
            (f32::NAN, 0),
            (-f32::NAN, 0),
            (f32::NEG_INFINITY, 0),
            (-3.0, 0),
            (f32::INFINITY, 255),
            (7.0, 255),
        ] {
            assert_eq!(unit_to_byte(v), byte, "{v}");
        }
    }
}
