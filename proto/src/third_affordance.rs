//! A third affordance (`Affordance::Open`, compiled into this crate's tests
//! only) added in the task's definition alone: the task's layout and action
//! space grow by what the affordance needs, and the wire carries its
//! labelled frames and metrics without a new message kind, field or schema
//! version.

use crate::{
    decode, encode, Affordance, AffordanceStat, EpisodeStats, FrameBatch, Limits, Message,
    MessageHeader, StatField, StatKey, TaskSpec, GRID_CELLS, LABEL_NEGATIVE, LABEL_POSITIVE,
    LABEL_UNKNOWN,
};

const LIMITS: Limits = Limits {
    max_actors: 4,
    max_payload_len: 1 << 20,
};

fn task(affordances: Vec<Affordance>) -> TaskSpec {
    TaskSpec {
        affordances,
        image_size: 64,
        ..TaskSpec::default()
    }
}

#[test]
fn the_third_affordance_has_its_own_code_and_name() {
    assert_eq!(Affordance::ALL.len(), 3);
    assert_eq!(Affordance::from_code(2), Some(Affordance::Open));
    assert_eq!(Affordance::Open.as_str(), "open");
    let names: std::collections::BTreeSet<_> = StatKey::all().map(StatKey::name).collect();
    assert!(names.contains("open_success_rate"), "{names:?}");
    assert_eq!(names.len(), StatKey::all().count());
}

#[test]
fn the_task_grows_by_one_affordance_worth_of_inputs_and_actions() {
    let two = task(vec![Affordance::PickUp, Affordance::Push]);
    let three = task(vec![Affordance::PickUp, Affordance::Push, Affordance::Open]);
    three
        .validate()
        .expect("a task with three affordances is valid");
    assert_eq!(three.n_actions(), two.n_actions() + GRID_CELLS);
    let (two, three) = (two.layout(), three.layout());
    assert_eq!(three.image_channels.len(), two.image_channels.len());
    for (a, b) in two.image_channels.iter().zip(&three.image_channels) {
        assert!(
            b > a,
            "each image input carries the new affordance's planes"
        );
    }
    assert_eq!(three.vector_dims.len(), two.vector_dims.len());
}

#[test]
fn its_metrics_cross_the_wire_under_the_same_schema() {
    let stats = EpisodeStats::new(9, 600, 2)
        .with(StatField::EpisodeReturn, 3.5)
        .with(
            StatKey::Affordance(Affordance::Push, AffordanceStat::SuccessRate),
            0.25,
        )
        .with(
            StatKey::Affordance(Affordance::Open, AffordanceStat::AttemptRate),
            0.125,
        )
        .with(
            StatKey::Affordance(Affordance::Open, AffordanceStat::Iou),
            0.5,
        );
    let bytes = encode(&stats, MessageHeader::default());
    match decode(&bytes, &LIMITS).expect("decodes").1 {
        Message::Stats(got) => {
            assert_eq!(*got, stats);
            assert_eq!(
                got.get(StatKey::Affordance(Affordance::Open, AffordanceStat::Iou)),
                Some(0.5)
            );
        }
        other => panic!("not stats: {:?}", other.kind()),
    }
}

#[test]
fn its_label_planes_cross_the_wire_as_one_more_plane() {
    let (frames, side, planes) = (2usize, 4usize, 3usize);
    let pixels = side * side;
    let batch = FrameBatch {
        episode_id: 4,
        height: side as u32,
        width: side as u32,
        n_affordances: planes as u32,
        depth_m: (0..frames * pixels)
            .map(|i| 0.5 + i as f32 / 100.0)
            .collect(),
        rgb: (0..frames * pixels * 3).map(|i| i as u8).collect(),
        labels: (0..frames * planes * pixels)
            .map(|i| [LABEL_POSITIVE, LABEL_NEGATIVE, LABEL_UNKNOWN][i % 3])
            .collect(),
    };
    let bytes = encode(&batch, MessageHeader::default());
    match decode(&bytes, &LIMITS).expect("decodes").1 {
        Message::Frames(view) => {
            let got = view.to_owned();
            assert_eq!(got, batch);
            assert_eq!(got.n_frames(), frames);
        }
        other => panic!("not frames: {:?}", other.kind()),
    }
}
