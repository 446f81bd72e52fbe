//! The linear algebra of one ICP iteration: Gauss-Newton normal equations
//! of a rigid twist, solved within a motion model ([`MotionModel`]) and only
//! along the directions the pairs constrain.

use nalgebra::{DMatrix, DVector, Matrix6, Point3, UnitQuaternion, Vector3, Vector6};

use crate::Pose;

/// Which motions an alignment may find.
///
/// Objects a robot pushes slide and turn on their support; they rise or tip
/// over rarely. A partial view of a thin or flat-sided object (a chair's
/// legs and seat, 36–73 pixels of one side) constrains a tilt or a lift
/// poorly, and a free alignment trades a few millimetres of fit for motions
/// the object never made: 10° and 18.6° of tilt for pushed chairs that
/// tilted 2.5° in `ours` episodes (checked against the simulator's poses),
/// a 7.4 cm lift in the mapper's chair test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionModel {
    /// Any rigid motion.
    Free,
    /// Sliding and turning on a horizontal support: translation
    /// perpendicular to `up`, rotation about it.
    Planar {
        /// The world's up direction in the camera frame (unit length).
        up: Vector3<f32>,
    },
    /// Standing as before wherever it is: any translation, rotation about
    /// `up` only (an object that fell off its support without tipping).
    Upright {
        /// The world's up direction in the camera frame (unit length).
        up: Vector3<f32>,
    },
}

/// Directions of the normal equations weaker than this fraction of the
/// strongest are treated as unobservable.
const DEGENERATE_EIGENVALUE_RATIO: f64 = 1e-3;

/// Gauss-Newton normal equations of a twist `(ω, v)` applied about the
/// camera-frame point `centre`: `p ↦ centre + R(ω)(p − centre) + v`. Rotating
/// about the object's centre rather than the camera's keeps rotation and
/// translation decoupled and the equations well conditioned.
pub(super) struct NormalEquations {
    pub(super) centre: Point3<f32>,
    jtj: Matrix6<f64>,
    jtr: Vector6<f64>,
    rows: usize,
}

impl NormalEquations {
    pub(super) fn new(centre: Point3<f32>) -> Self {
        Self {
            centre,
            jtj: Matrix6::zeros(),
            jtr: Vector6::zeros(),
            rows: 0,
        }
    }

    /// Adds residual `r` with rotation and translation Jacobians, Huber-weighted at `huber_m`.
    pub(super) fn add(&mut self, r: f32, d_omega: Vector3<f32>, d_v: Vector3<f32>, huber_m: f32) {
        // Huber weight: residuals far off the surface (edges, mixed pixels) pull less.
        let w = f64::from(if r.abs() <= huber_m {
            1.0
        } else {
            huber_m / r.abs()
        });
        let j = Vector6::new(d_omega.x, d_omega.y, d_omega.z, d_v.x, d_v.y, d_v.z).cast::<f64>();
        self.jtj += j * j.transpose() * w;
        self.jtr += j * (f64::from(r) * w);
        self.rows += 1;
    }

    /// The step minimising the residuals, in the well-constrained directions
    /// only: a plane seen alone says nothing about sliding along it, so those
    /// directions keep the current estimate instead of drifting. `None` when
    /// there is too little to solve; else the step and its size.
    ///
    /// Within `motion`: for [`MotionModel::Planar`] the twist is
    /// `(θ·up, v)` with `v ⊥ up`, solved for θ and `v`'s two components in
    /// the same way; for [`MotionModel::Upright`], for θ and all of `v`.
    pub(super) fn solve(&self, motion: MotionModel) -> Option<(Pose, f32)> {
        if self.rows < 6 {
            return None;
        }
        let x = match motion {
            MotionModel::Free => {
                let jtj = DMatrix::from_column_slice(6, 6, self.jtj.as_slice());
                let jtr = DVector::from_column_slice(self.jtr.as_slice());
                Vector6::from_column_slice(well_constrained_step(jtj, &jtr)?.as_slice())
            }
            MotionModel::Planar { up } | MotionModel::Upright { up } => {
                // Columns: the rotation about `up`, then translations along
                // two directions perpendicular to it, then (upright) along it.
                let lifts = matches!(motion, MotionModel::Upright { .. });
                let up = up.cast::<f64>();
                let across = up.cross(&Vector3::x()).try_normalize(1e-6);
                let across = across.unwrap_or_else(|| up.cross(&Vector3::y()).normalize());
                let along = up.cross(&across);
                let mut basis = DMatrix::<f64>::zeros(6, if lifts { 4 } else { 3 });
                for a in 0..3 {
                    basis[(a, 0)] = up[a];
                    basis[(3 + a, 1)] = across[a];
                    basis[(3 + a, 2)] = along[a];
                    if lifts {
                        basis[(3 + a, 3)] = up[a];
                    }
                }
                let jtj = basis.transpose() * self.jtj * &basis;
                let jtr = basis.transpose() * self.jtr;
                let y = well_constrained_step(jtj, &jtr)?;
                Vector6::from_column_slice((basis * y).as_slice())
            }
        };
        let x = x.cast::<f32>();
        let omega = Vector3::new(x[0], x[1], x[2]);
        let v = Vector3::new(x[3], x[4], x[5]);
        let c = self.centre;
        let step = Pose::from_parts(
            (c.coords + v).into(),
            UnitQuaternion::from_scaled_axis(omega),
        ) * Pose::translation(-c.x, -c.y, -c.z);
        Some((step, v.norm().max(omega.norm())))
    }
}

/// The Gauss-Newton step `-JᵀJ⁻¹ Jᵀr` along the eigenvectors of `jtj`
/// that are not degenerate ([`DEGENERATE_EIGENVALUE_RATIO`]); `None` when
/// nothing is constrained.
fn well_constrained_step(jtj: DMatrix<f64>, jtr: &DVector<f64>) -> Option<DVector<f64>> {
    let eigen = jtj.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if largest <= 0.0 {
        return None;
    }
    let mut x = DVector::<f64>::zeros(jtr.len());
    for (i, &lambda) in eigen.eigenvalues.iter().enumerate() {
        if lambda > DEGENERATE_EIGENVALUE_RATIO * largest {
            let axis = eigen.eigenvectors.column(i);
            x -= axis * (axis.dot(jtr) / lambda);
        }
    }
    Some(x)
}
