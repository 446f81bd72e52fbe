//! The paper's Tables 1 and 2 (Wulkop, Özdemir et al., AI2-THOR, 611 test
//! frames and 236 objects), for the rows beside ours. Its simulator, robot
//! and step budget differ from this project's: these are a reference for
//! the ordering of the methods, not numbers to match.

/// One method's published scores.
pub(crate) struct PaperRow {
    /// The paper's name for it.
    pub name: &'static str,
    /// Table 1 medians per affordance (pick up, push): precision, recall,
    /// F1, object accuracy.
    pub pixel: [[f32; 4]; 2],
    /// Table 2 per affordance (pick up, push): accuracy, precision,
    /// recall, F1.
    pub object: [[f32; 4]; 2],
}

/// The paper's four methods.
pub(crate) const PAPER: [PaperRow; 4] = [
    PaperRow {
        name: "Ours",
        pixel: [[0.20, 0.37, 0.22, 0.89], [0.99, 0.48, 0.60, 0.76]],
        object: [[0.81, 0.85, 0.47, 0.60], [0.61, 0.90, 0.43, 0.58]],
    },
    PaperRow {
        name: "No Map + Seg",
        pixel: [[0.10, 0.22, 0.13, 0.87], [0.52, 0.83, 0.58, 0.80]],
        object: [[0.75, 0.76, 0.30, 0.43], [0.72, 0.94, 0.60, 0.73]],
    },
    PaperRow {
        name: "No Map + No Seg",
        pixel: [[0.00, 0.00, 0.00, 0.82], [0.30, 0.93, 0.44, 0.70]],
        object: [[0.69, 0.50, 0.03, 0.05], [0.76, 0.77, 0.91, 0.83]],
    },
    PaperRow {
        name: "IntExp",
        pixel: [[0.03, 0.07, 0.04, 0.86], [0.36, 0.52, 0.41, 0.65]],
        object: [[0.72, 0.75, 0.12, 0.21], [0.58, 0.76, 0.51, 0.61]],
    },
];

/// The paper's index of an affordance's rows (`None` for one it did not report).
pub(crate) fn affordance_index(affordance: &str) -> Option<usize> {
    match affordance {
        "pick_up" => Some(0),
        "push" => Some(1),
        _ => None,
    }
}
