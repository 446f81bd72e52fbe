//! Property tests of the decoder: every good message round-trips, every damaged
//! one is rejected with a typed error, and no input makes it panic.

use proptest::prelude::*;
use proto::{
    decode, decode_header, decode_weights, encode, Affordance, EpisodeStats, FrameBatch, JoinKey,
    Limits, Message, MessageHeader, MessageKind, ObsDtype, ProtoError, RolloutChunk, StatField,
    StatKey, TypeTries, WeightsBlob, HEADER_LEN, JOIN_KEY_LEN, LEARNER_ID, WEIGHTS_TAG_LEN,
};

const LIMITS: Limits = Limits {
    max_actors: 16,
    max_payload_len: 64 << 20,
};

fn header(actor_id: u32, sequence: u64) -> MessageHeader {
    MessageHeader {
        magic: 0,
        schema_version: 0,
        kind: 0,
        actor_id,
        checksum: 0,
        policy_version: 3,
        unet_version: 5,
        sequence,
        payload_len: 0,
    }
}

fn rollout_strategy() -> impl Strategy<Value = RolloutChunk> {
    (1usize..20, 1u32..12, 0u32..8, any::<bool>(), any::<u64>()).prop_flat_map(
        |(t, n_actions, obs_elems, f32_obs, episode_id)| {
            let dtype = if f32_obs { ObsDtype::F32 } else { ObsDtype::U8 };
            let obs_len = t * obs_elems as usize;
            (
                prop::collection::vec(any::<u8>(), obs_len),
                prop::collection::vec(-10.0f32..10.0, obs_len),
                prop::collection::vec(prop::collection::vec(any::<bool>(), n_actions as usize), t),
                prop::collection::vec(0u32..n_actions, t),
                prop::collection::vec(-20.0f32..0.0, t),
                prop::collection::vec(-5.0f32..5.0, 2 * t),
                prop::collection::vec(0u8..2, t),
                0u32..600,
            )
                .prop_map(
                    move |(
                        obs_u8,
                        obs_f32,
                        mut masks,
                        actions,
                        log_probs,
                        vr,
                        dones,
                        first_step,
                    )| {
                        for (m, &a) in masks.iter_mut().zip(&actions) {
                            m[a as usize] = true;
                        }
                        let obs = match dtype {
                            ObsDtype::U8 => obs_u8,
                            ObsDtype::F32 => proto::obs_bytes_from_f32(&obs_f32),
                        };
                        RolloutChunk {
                            episode_id,
                            first_step,
                            n_actions,
                            obs_dtype: dtype,
                            obs_elems,
                            obs,
                            masks: masks.into_iter().flatten().map(u8::from).collect(),
                            actions,
                            log_probs,
                            values: vr[..t].to_vec(),
                            rewards: vr[t..].to_vec(),
                            dones,
                            bootstrap_value: 0.5,
                            start_hidden: if first_step % 2 == 0 {
                                Vec::new()
                            } else {
                                vr[..t].to_vec()
                            },
                        }
                    },
                )
        },
    )
}

fn frames_strategy() -> impl Strategy<Value = FrameBatch> {
    (1u32..4, 1u32..9, 1u32..9, 1u32..3).prop_flat_map(|(n, h, w, a)| {
        let px = (n * h * w) as usize;
        (
            prop::collection::vec(0.0f32..10.0, px),
            prop::collection::vec(any::<u8>(), 3 * px),
            prop::collection::vec(prop::sample::select(vec![0u8, 1, 255]), px * a as usize),
            any::<u64>(),
        )
            .prop_map(move |(depth_m, rgb, labels, episode_id)| FrameBatch {
                episode_id,
                height: h,
                width: w,
                n_affordances: a,
                depth_m,
                rgb,
                labels,
            })
    })
}

fn stats_strategy() -> impl Strategy<Value = EpisodeStats> {
    (
        any::<u64>(),
        any::<u32>(),
        0u32..30,
        prop::collection::vec(prop::option::of(0.0f32..1.0), StatKey::all().count()),
        prop::collection::vec(
            (
                any::<bool>(),
                "[A-Za-z_]{1,12}",
                1u32..20,
                0u32..20,
                1u32..20,
            ),
            0..6,
        ),
    )
        .prop_map(|(id, steps, scene, values, tries)| {
            let tries = tries
                .into_iter()
                .map(|(push, name, attempts, s, o)| TypeTries {
                    affordance: if push {
                        Affordance::Push
                    } else {
                        Affordance::PickUp
                    },
                    object_type: name,
                    attempts,
                    successes: s.min(attempts),
                    objects: o.min(attempts),
                });
            StatKey::all()
                .zip(values)
                .fold(EpisodeStats::new(id, steps, scene), |s, (key, v)| match v {
                    Some(v) => s.with(key, v),
                    None => s,
                })
                .with_tries(tries)
        })
}

fn weights_bytes(values: &[f32]) -> Vec<u8> {
    let data: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let view =
        safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![values.len()], &data)
            .unwrap();
    safetensors::serialize([("policy.actor.0.weight", view)], None).unwrap()
}

fn run_key() -> JoinKey {
    JoinKey::from_bytes([9; JOIN_KEY_LEN])
}

/// A weights message holding `values`, signed with [`run_key`].
fn signed_weights(values: &[f32], header: MessageHeader) -> Vec<u8> {
    let blob = weights_bytes(values);
    encode(&WeightsBlob::signed(&run_key(), &header, &blob), header)
}

/// One valid encoded message of any kind.
fn any_message() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        rollout_strategy().prop_map(|c| encode(&c, header(1, 1))),
        frames_strategy().prop_map(|f| encode(&f, header(2, 2))),
        stats_strategy().prop_map(|s| encode(&s, header(3, 3))),
        prop::collection::vec(-1.0f32..1.0, 1..16)
            .prop_map(|v| signed_weights(&v, header(LEARNER_ID, 4))),
    ]
}

proptest! {
    #[test]
    fn rollouts_round_trip(chunk in rollout_strategy()) {
        let bytes = encode(&chunk, header(7, 42));
        let (h, msg) = decode(&bytes, &LIMITS).unwrap();
        prop_assert_eq!(h.sequence, 42);
        prop_assert_eq!(h.actor_id, 7);
        prop_assert_eq!((h.policy_version, h.unet_version), (3, 5));
        match msg {
            Message::Rollout(view) => prop_assert_eq!(view.to_owned(), chunk),
            other => prop_assert!(false, "wrong kind {:?}", other.kind()),
        }
    }

    #[test]
    fn frames_round_trip(batch in frames_strategy()) {
        let bytes = encode(&batch, header(0, 1));
        match decode(&bytes, &LIMITS).unwrap().1 {
            Message::Frames(view) => prop_assert_eq!(view.to_owned(), batch),
            other => prop_assert!(false, "wrong kind {:?}", other.kind()),
        }
    }

    #[test]
    fn a_range_of_frames_decodes_to_those_frames(batch in frames_strategy(), cut in 0usize..4) {
        let n = batch.n_frames();
        let (start, end) = (cut.min(n - 1), n);
        let bytes = encode(&batch.frames(start..end), header(0, 1));
        let pixels = (batch.height * batch.width) as usize;
        let planes = batch.n_affordances as usize;
        let expected = FrameBatch {
            depth_m: batch.depth_m[start * pixels..].to_vec(),
            rgb: batch.rgb[3 * start * pixels..].to_vec(),
            labels: batch.labels[planes * start * pixels..].to_vec(),
            ..batch.clone()
        };
        match decode(&bytes, &LIMITS).unwrap().1 {
            Message::Frames(view) => prop_assert_eq!(view.to_owned(), expected),
            other => prop_assert!(false, "wrong kind {:?}", other.kind()),
        }
    }

    #[test]
    fn stats_round_trip(stats in stats_strategy()) {
        let bytes = encode(&stats, header(0, 1));
        match decode(&bytes, &LIMITS).unwrap().1 {
            Message::Stats(got) => prop_assert_eq!(*got, stats),
            other => prop_assert!(false, "wrong kind {:?}", other.kind()),
        }
    }

    #[test]
    fn weights_round_trip(values in prop::collection::vec(-1.0f32..1.0, 1..64)) {
        let blob = weights_bytes(&values);
        let bytes = signed_weights(&values, header(LEARNER_ID, 9));
        let (h, view) = decode_weights(&bytes, &LIMITS, &run_key()).unwrap();
        prop_assert_eq!(view.bytes(), &blob[..]);
        prop_assert_eq!((h.policy_version, h.unet_version, h.sequence), (3, 5, 9));
    }

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = decode(&bytes, &LIMITS);
    }

    #[test]
    fn every_truncation_is_rejected(bytes in any_message(), cut in any::<prop::sample::Index>()) {
        let cut = cut.index(bytes.len());
        prop_assert!(decode(&bytes[..cut], &LIMITS).is_err());
    }

    #[test]
    fn every_payload_bit_flip_is_rejected(bytes in any_message(), at in any::<prop::sample::Index>(), bit in 0u8..8) {
        let mut bytes = bytes;
        let at = HEADER_LEN + at.index(bytes.len() - HEADER_LEN);
        bytes[at] ^= 1 << bit;
        let rejected = matches!(decode(&bytes, &LIMITS), Err(ProtoError::BadChecksum { .. }));
        prop_assert!(rejected);
    }

    #[test]
    fn damaged_headers_are_rejected(bytes in any_message(), field in 0usize..5, value in any::<u32>()) {
        let mut bytes = bytes;
        let original = bytes.clone();
        match field {
            0 => bytes[0..4].copy_from_slice(&value.to_le_bytes()),
            1 => bytes[4..6].copy_from_slice(&(value as u16).to_le_bytes()),
            2 => bytes[6..8].copy_from_slice(&(value as u16 % 8).to_le_bytes()),
            3 => bytes[12..16].copy_from_slice(&value.to_le_bytes()),
            _ => bytes[40..48].copy_from_slice(&u64::from(value).to_le_bytes()),
        }
        prop_assume!(bytes != original);
        match decode(&bytes, &LIMITS) {
            Err(_) => {}
            // The checksum covers the payload, not the kind: a payload that
            // also happens to be a valid layout of another kind (an 80-byte
            // frame batch read as a join) decodes as that kind, and its
            // contents then face that kind's own checks (a join's proof).
            Ok((_, message)) => prop_assert!(
                field == 2,
                "{:?} accepted after damage to header field {field}",
                message.kind()
            ),
        }
    }

    #[test]
    fn the_header_alone_agrees_with_the_whole_decode(bytes in any_message()) {
        let (header, message) = decode(&bytes, &LIMITS).unwrap();
        prop_assert_eq!(decode_header(&bytes, &LIMITS).unwrap(), (header, message.kind()));
    }

    #[test]
    fn the_header_alone_refuses_truncations_and_damaged_envelopes(bytes in any_message(), cut in any::<prop::sample::Index>(), field in 0usize..3, value in any::<u32>()) {
        let cut = cut.index(bytes.len());
        prop_assert!(decode_header(&bytes[..cut], &LIMITS).is_err());
        let mut damaged = bytes.clone();
        match field {
            0 => damaged[0..4].copy_from_slice(&value.to_le_bytes()),
            1 => damaged[4..6].copy_from_slice(&(value as u16).to_le_bytes()),
            _ => damaged[40..48].copy_from_slice(&u64::from(value).to_le_bytes()),
        }
        prop_assume!(damaged != bytes);
        prop_assert!(decode_header(&damaged, &LIMITS).is_err());
    }

    #[test]
    fn the_header_alone_does_not_read_the_payload(bytes in any_message(), at in any::<prop::sample::Index>(), bit in 0u8..8) {
        // What it leaves to the receiver's whole decode: a flipped payload bit.
        let mut bytes = bytes;
        let at = HEADER_LEN + at.index(bytes.len() - HEADER_LEN);
        bytes[at] ^= 1 << bit;
        prop_assert!(decode_header(&bytes, &LIMITS).is_ok());
        prop_assert!(decode(&bytes, &LIMITS).is_err());
    }

    #[test]
    fn random_bytes_never_make_the_header_check_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = decode_header(&bytes, &LIMITS);
    }

    #[test]
    fn payload_corruption_with_a_fixed_checksum_never_panics(bytes in any_message(), at in any::<prop::sample::Index>(), byte in any::<u8>()) {
        // An attacker (or a bug) that rewrites the checksum too must still meet the layout checks.
        let mut bytes = bytes;
        let at = HEADER_LEN + at.index(bytes.len() - HEADER_LEN);
        bytes[at] = byte;
        let crc = crc32fast::hash(&bytes[HEADER_LEN..]);
        bytes[12..16].copy_from_slice(&crc.to_le_bytes());
        let _ = decode(&bytes, &LIMITS);
    }
}

fn reencode_with_fixed_checksum(mut bytes: Vec<u8>, edit: impl FnOnce(&mut [u8])) -> Vec<u8> {
    edit(&mut bytes[HEADER_LEN..]);
    let crc = crc32fast::hash(&bytes[HEADER_LEN..]);
    bytes[12..16].copy_from_slice(&crc.to_le_bytes());
    bytes
}

fn small_chunk() -> RolloutChunk {
    RolloutChunk {
        episode_id: 1,
        first_step: 0,
        n_actions: 3,
        obs_dtype: ObsDtype::F32,
        obs_elems: 2,
        obs: proto::obs_bytes_from_f32(&[0.0, 1.0, 2.0, 3.0]),
        actions: vec![0, 2],
        masks: vec![1, 0, 0, 0, 0, 1],
        log_probs: vec![-0.1, -0.2],
        values: vec![0.0, 0.0],
        rewards: vec![1.0, 0.0],
        dones: vec![0, 1],
        bootstrap_value: 0.0,
        start_hidden: vec![0.5, -0.5],
    }
}

#[test]
fn non_finite_values_are_rejected_even_with_a_valid_checksum() {
    let mut chunk = small_chunk();
    chunk.rewards[1] = f32::NAN;
    let err = decode(&encode(&chunk, header(0, 0)), &LIMITS).unwrap_err();
    assert!(
        matches!(
            err,
            ProtoError::BadFloat {
                field: "rewards",
                index: 1,
                ..
            }
        ),
        "{err}"
    );

    let mut chunk = small_chunk();
    chunk.start_hidden[1] = f32::NAN;
    let err = decode(&encode(&chunk, header(0, 0)), &LIMITS).unwrap_err();
    assert!(
        matches!(
            err,
            ProtoError::BadFloat {
                field: "start_hidden",
                ..
            }
        ),
        "{err}"
    );

    let mut chunk = small_chunk();
    chunk.obs = proto::obs_bytes_from_f32(&[0.0, f32::INFINITY, 2.0, 3.0]);
    let err = decode(&encode(&chunk, header(0, 0)), &LIMITS).unwrap_err();
    assert!(
        matches!(err, ProtoError::BadFloat { field: "obs", .. }),
        "{err}"
    );
}

#[test]
fn masked_and_out_of_range_actions_are_rejected() {
    let mut chunk = small_chunk();
    chunk.actions[0] = 1;
    let err = decode(&encode(&chunk, header(0, 0)), &LIMITS).unwrap_err();
    assert_eq!(err, ProtoError::MaskedAction { step: 0, action: 1 });

    let bytes = reencode_with_fixed_checksum(encode(&small_chunk(), header(0, 0)), |p| {
        // After the 36-byte sub-header and the two-value start state.
        p[44..48].copy_from_slice(&7u32.to_le_bytes());
    });
    assert!(matches!(
        decode(&bytes, &LIMITS),
        Err(ProtoError::OutOfRange {
            field: "actions",
            ..
        })
    ));
}

#[test]
fn ids_out_of_range_are_rejected() {
    let bytes = encode(&small_chunk(), header(LIMITS.max_actors, 0));
    assert!(matches!(
        decode(&bytes, &LIMITS),
        Err(ProtoError::OutOfRange {
            field: "actor_id",
            ..
        })
    ));
    let bytes = signed_weights(&[1.0], header(0, 0));
    assert!(matches!(
        decode(&bytes, &LIMITS),
        Err(ProtoError::OutOfRange {
            field: "actor_id",
            ..
        })
    ));
}

#[test]
fn lengths_that_disagree_are_rejected() {
    let bytes = reencode_with_fixed_checksum(encode(&small_chunk(), header(0, 0)), |p| {
        p[12..16].copy_from_slice(&3u32.to_le_bytes()); // n_steps 2 -> 3
    });
    assert!(matches!(
        decode(&bytes, &LIMITS),
        Err(ProtoError::LayoutMismatch {
            what: "rollout",
            ..
        })
    ));
    let small = Limits {
        max_actors: 16,
        max_payload_len: 16,
    };
    assert!(matches!(
        decode(&encode(&small_chunk(), header(0, 0)), &small),
        Err(ProtoError::PayloadTooLarge { .. })
    ));
}

#[test]
fn bad_labels_and_negative_depth_are_rejected() {
    let batch = FrameBatch {
        episode_id: 0,
        height: 1,
        width: 2,
        n_affordances: 1,
        depth_m: vec![1.0, -1.0],
        rgb: vec![0; 6],
        labels: vec![0, 1],
    };
    assert!(matches!(
        decode(&encode(&batch, header(0, 0)), &LIMITS),
        Err(ProtoError::BadFloat {
            field: "depth_m",
            ..
        })
    ));
    let batch = FrameBatch {
        depth_m: vec![1.0, 1.0],
        labels: vec![0, 2],
        ..batch
    };
    assert!(matches!(
        decode(&encode(&batch, header(0, 0)), &LIMITS),
        Err(ProtoError::OutOfRange {
            field: "labels",
            ..
        })
    ));
}

#[test]
fn out_of_range_rates_are_rejected() {
    let stats = EpisodeStats::new(0, 600, 0).with(StatField::InteractionSuccessRate, 1.5);
    let err = decode(&encode(&stats, header(0, 0)), &LIMITS).unwrap_err();
    assert!(
        matches!(
            err,
            ProtoError::BadFloat {
                field: "interaction_success_rate",
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn kinds_have_distinct_services() {
    let names: std::collections::HashSet<_> = MessageKind::ALL
        .iter()
        .map(|&k| proto::service::for_kind(k))
        .collect();
    assert_eq!(names.len(), 4);
}

/// The signature as the wire format documents it, computed here with the
/// `hmac` crate directly: HMAC-SHA256 with the run key over the context,
/// the header's policy version, U-Net version and sequence (u64 LE) and the
/// safetensors bytes.
fn reference_tag(key: &[u8], header: &MessageHeader, safetensors: &[u8]) -> Vec<u8> {
    use hmac::{Hmac, Mac};
    let mut mac = Hmac::<sha2::Sha256>::new_from_slice(key).unwrap();
    mac.update(b"affordance-explorer weights v1");
    mac.update(&header.policy_version.to_le_bytes());
    mac.update(&header.unet_version.to_le_bytes());
    mac.update(&header.sequence.to_le_bytes());
    mac.update(safetensors);
    mac.finalize().into_bytes().to_vec()
}

#[test]
fn weights_carry_the_documented_signature_before_the_safetensors() {
    let h = header(LEARNER_ID, 11);
    let bytes = signed_weights(&[0.5, -0.25], h);
    let blob = weights_bytes(&[0.5, -0.25]);
    let payload = &bytes[HEADER_LEN..];
    assert_eq!(payload.len(), WEIGHTS_TAG_LEN + blob.len());
    assert_eq!(
        &payload[..WEIGHTS_TAG_LEN],
        &reference_tag(&[9; JOIN_KEY_LEN], &h, &blob)[..]
    );
    assert_eq!(&payload[WEIGHTS_TAG_LEN..], &blob[..]);
}

#[test]
fn weights_signed_with_another_key_are_refused() {
    let h = header(LEARNER_ID, 1);
    let blob = weights_bytes(&[1.0, 2.0]);
    let foreign = JoinKey::from_bytes([1; JOIN_KEY_LEN]);
    let bytes = encode(&WeightsBlob::signed(&foreign, &h, &blob), h);
    // Structurally fine: the plain decoder accepts it ...
    assert!(matches!(
        decode(&bytes, &LIMITS),
        Ok((_, Message::Weights(_)))
    ));
    // ... the weights decoder does not.
    assert_eq!(
        decode_weights(&bytes, &LIMITS, &run_key()).unwrap_err(),
        ProtoError::BadSignature
    );
    assert_eq!(ProtoError::BadSignature.reason(), "bad_signature");
}

#[test]
fn weights_edited_after_signing_are_refused_even_with_a_fixed_checksum() {
    let good = signed_weights(&[1.0, 2.0, 3.0], header(LEARNER_ID, 5));
    assert!(decode_weights(&good, &LIMITS, &run_key()).is_ok());
    // A different policy version in the header (the payload, and so the
    // checksum, unchanged).
    let mut relabelled = good.clone();
    relabelled[16..24].copy_from_slice(&99u64.to_le_bytes());
    // One tensor value changed, checksum recomputed.
    let last = good.len() - 1;
    let edited = reencode_with_fixed_checksum(good.clone(), |p| {
        p[last - HEADER_LEN] ^= 0x01;
    });
    // The tag itself replaced by zeros, checksum recomputed.
    let zeroed = reencode_with_fixed_checksum(good, |p| p[..WEIGHTS_TAG_LEN].fill(0));
    for bytes in [relabelled, edited, zeroed] {
        assert_eq!(
            decode_weights(&bytes, &LIMITS, &run_key()).unwrap_err(),
            ProtoError::BadSignature
        );
    }
}

#[test]
fn weights_shorter_than_their_signature_and_other_kinds_are_refused() {
    let full = signed_weights(&[1.0], header(LEARNER_ID, 1));
    let cut = {
        let mut b = full[..HEADER_LEN + 7].to_vec();
        b[40..48].copy_from_slice(&7u64.to_le_bytes());
        reencode_with_fixed_checksum(b, |_| {})
    };
    assert!(matches!(
        decode_weights(&cut, &LIMITS, &run_key()),
        Err(ProtoError::Truncated {
            what: "weights signature",
            ..
        })
    ));
    let rollout = encode(&small_chunk(), header(0, 0));
    assert!(matches!(
        decode_weights(&rollout, &LIMITS, &run_key()),
        Err(ProtoError::WrongKind {
            expected: MessageKind::Weights,
            got: MessageKind::Rollout
        })
    ));
}
