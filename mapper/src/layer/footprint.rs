//! An object's surface as the floor plane sees it from one pose, kept by
//! its layer between steps: the actor's state projects every placed
//! object's surface points onto its egocentric grids each step, while most
//! objects neither move nor change their surface in a step. Moving each
//! point into the world and testing its height was most of that work
//! (docs/notebook/2026-12-01-kept-footprints.md); a kept footprint leaves
//! one cell lookup per voxel column and grid.

use std::sync::{Arc, Mutex, PoisonError};

use nalgebra::Point3;

use super::Layer;
use crate::Pose;

impl Layer {
    /// `pose` moving [`Layer::surface_centres`] into the world, as columns
    /// with the height `bands` their points reach
    /// ([`crate::Map::surface_points`]' rasterising): kept until the
    /// surface may change or another pose or bands are asked for (most
    /// objects are not touched in a step).
    pub(crate) fn surface_footprint(&self, pose: &Pose, bands: &[Band]) -> Arc<Footprint> {
        (self.surface_footprint).get_or_make(pose, bands, || {
            Footprint::new(self.surface_centres(), pose, bands)
        })
    }
}

/// A height band of occupancy projections, world z in metres: `[min, max]`,
/// both included.
pub(crate) type Band = [f32; 2];

/// Whether height `z` lies within `band` (both ends included), as every
/// occupancy projection tests it.
#[inline]
pub(crate) fn band_holds([min, max]: Band, z: f32) -> bool {
    min <= z && z <= max
}

/// Most distinct height bands one footprint tells apart (a bit each).
pub(crate) const MAX_BANDS: usize = 64;

/// One voxel column of an upright object (its surface points that share
/// an x and y in the object's frame, so in the world's), or one point of
/// an object that is not upright.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FootprintColumn {
    /// World x of the column's first point, metres.
    pub(crate) x: f32,
    /// World y of the column's first point, metres.
    pub(crate) y: f32,
    /// Bit `i` set where a point of the column lies within band `i`.
    pub(crate) bands: u64,
}

/// A layer's surface points moved into the world by one pose, as columns
/// with the height bands they reach; what rasterising them onto any grid
/// needs.
#[derive(Debug, PartialEq)]
pub(crate) struct Footprint {
    /// The pose it was made with.
    pose: Pose,
    /// The bands its columns' bits stand for, in bit order.
    bands: Vec<Band>,
    columns: Vec<FootprintColumn>,
}

impl Footprint {
    /// `points` (a layer's [`crate::Layer::surface_centres`], a voxel column
    /// at a time) moved by `pose`. Turned about z alone, an object moves
    /// its points' x and y whatever their z, so the consecutive points of
    /// one voxel column make one column (the first point's world x and y);
    /// turned any other way, each point is its own. Every point is moved
    /// as [`Pose`]'s product moves it, so that its heights and cells are
    /// the ones a point-by-point scan finds.
    ///
    /// # Panics
    ///
    /// With more than [`MAX_BANDS`] bands.
    pub(crate) fn new(points: &[Point3<f32>], pose: &Pose, bands: &[Band]) -> Self {
        assert!(bands.len() <= MAX_BANDS, "at most {MAX_BANDS} height bands");
        let rotation = &pose.rotation;
        let upright = rotation.i == 0.0 && rotation.j == 0.0;
        let mut columns: Vec<FootprintColumn> = Vec::new();
        let mut last = None;
        for centre in points {
            let p = pose * centre;
            let reached = (bands.iter().enumerate())
                .filter(|(_, &band)| band_holds(band, p.z))
                .fold(0u64, |reached, (i, _)| reached | 1 << i);
            let same_column = upright && last == Some((centre.x, centre.y));
            last = Some((centre.x, centre.y));
            match columns.last_mut() {
                Some(column) if same_column => column.bands |= reached,
                _ => columns.push(FootprintColumn {
                    x: p.x,
                    y: p.y,
                    bands: reached,
                }),
            }
        }
        Self {
            pose: *pose,
            bands: bands.to_vec(),
            columns,
        }
    }

    /// Whether it was made with `pose` and `bands`.
    fn made_for(&self, pose: &Pose, bands: &[Band]) -> bool {
        self.pose == *pose && self.bands == bands
    }

    /// Its columns.
    pub(crate) fn columns(&self) -> &[FootprintColumn] {
        &self.columns
    }
}

/// The footprint a layer keeps ([`crate::Layer::surface_footprint`]): the
/// last one asked for, until the layer's surface may change. Shared behind
/// a lock, as the layer is read through `&self`; a clone of the layer keeps
/// it (the clone's surface is the same).
#[derive(Debug, Default)]
pub(crate) struct KeptFootprint(Mutex<Option<Arc<Footprint>>>);

impl KeptFootprint {
    /// The kept footprint if it was made with `pose` and `bands`, else the
    /// one `make` makes, kept from now on.
    pub(crate) fn get_or_make(
        &self,
        pose: &Pose,
        bands: &[Band],
        make: impl FnOnce() -> Footprint,
    ) -> Arc<Footprint> {
        let mut kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        match &*kept {
            Some(footprint) if footprint.made_for(pose, bands) => Arc::clone(footprint),
            _ => Arc::clone(kept.insert(Arc::new(make()))),
        }
    }

    /// Forgets the kept footprint (the surface may change).
    pub(crate) fn forget(&mut self) {
        *self.0.get_mut().unwrap_or_else(PoisonError::into_inner) = None;
    }

    /// Whether a footprint is kept.
    #[cfg(test)]
    pub(crate) fn is_kept(&self) -> bool {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .is_some()
    }
}

impl Clone for KeptFootprint {
    fn clone(&self) -> Self {
        let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        Self(Mutex::new(kept.clone()))
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Vector3};

    use super::*;

    const BANDS: [Band; 2] = [[0.05, 1.8], [2.0, 3.0]];

    fn column_of(x: f32, y: f32, zs: &[f32]) -> Vec<Point3<f32>> {
        zs.iter().map(|&z| Point3::new(x, y, z)).collect()
    }

    #[test]
    fn an_upright_objects_columns_gather_their_points_heights() {
        let mut points = column_of(0.1, 0.2, &[0.0, 1.0, 2.5]);
        points.extend(column_of(0.3, 0.2, &[0.01]));
        let pose = Isometry3::new(Vector3::new(1.0, 2.0, 0.02), Vector3::z() * 0.5);
        let footprint = Footprint::new(&points, &pose, &BANDS);
        let first = pose * points[0];
        let last = pose * points[3];
        assert_eq!(
            footprint.columns(),
            [
                FootprintColumn {
                    x: first.x,
                    y: first.y,
                    bands: 0b11,
                },
                // 0.01 + 0.02 lies below the lowest band.
                FootprintColumn {
                    x: last.x,
                    y: last.y,
                    bands: 0,
                },
            ]
        );
    }

    #[test]
    fn a_tilted_objects_points_are_each_their_own_column() {
        let points = column_of(0.1, 0.2, &[0.5, 1.0, 2.5]);
        let pose = Isometry3::new(Vector3::zeros(), Vector3::new(0.3, 0.0, 0.0));
        let footprint = Footprint::new(&points, &pose, &BANDS);
        assert_eq!(footprint.columns().len(), 3);
        for (column, point) in footprint.columns().iter().zip(&points) {
            let p = pose * point;
            assert_eq!((column.x, column.y), (p.x, p.y));
        }
    }

    #[test]
    fn a_kept_footprint_serves_only_its_own_pose_and_bands() {
        let points = column_of(0.1, 0.2, &[0.5]);
        let mut kept = KeptFootprint::default();
        let pose = Isometry3::translation(1.0, 0.0, 0.0);
        let made = std::cell::Cell::new(0);
        let get = |kept: &KeptFootprint, pose: &Pose, bands: &[Band]| {
            kept.get_or_make(pose, bands, || {
                made.set(made.get() + 1);
                Footprint::new(&points, pose, bands)
            })
        };
        let first = get(&kept, &pose, &BANDS);
        assert!(Arc::ptr_eq(&first, &get(&kept, &pose, &BANDS)));
        assert_eq!(made.get(), 1);
        let moved = Isometry3::translation(1.0, 0.5, 0.0);
        assert_eq!(
            get(&kept, &moved, &BANDS).columns()[0].y,
            (moved * points[0]).y
        );
        assert_eq!(get(&kept, &moved, &BANDS[..1]).columns()[0].bands, 1);
        assert_eq!(made.get(), 3);
        assert!(kept.clone().is_kept());
        kept.forget();
        assert!(!kept.is_kept());
    }
}
