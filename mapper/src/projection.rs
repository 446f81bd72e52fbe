//! 2-D projections of the map onto the floor plane (world z is up), at any
//! extent and resolution, world-aligned or egocentric.

use nalgebra::{Point2, Point3};

use crate::labels::Affordance;
use crate::layer::floor_to_i32;
use crate::map::{Map, MapObject};

/// A square grid on the floor plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    /// Grid centre, world x / y in metres.
    pub center: Point2<f32>,
    /// Direction the grid's "up" (row 0 side) faces, radians from world +x
    /// counter-clockwise. Egocentric maps use the agent's heading.
    pub up_heading_rad: f32,
    /// Edge length in metres.
    pub extent_m: f32,
    /// Cells per edge.
    pub cells: usize,
}

impl GridSpec {
    /// Cell index of a world point, if inside.
    pub fn cell_of(&self, x: f32, y: f32) -> Option<usize> {
        CellLocator::new(self).cell_of(x, y)
    }
}

/// [`GridSpec::cell_of`] with the rotation and scale worked out once, for
/// rasterising many points (no trigonometry or libm call per point).
struct CellLocator {
    center: Point2<f32>,
    sin: f32,
    cos: f32,
    half_extent_m: f32,
    cell_m: f32,
    cells: usize,
}

impl CellLocator {
    fn new(grid: &GridSpec) -> Self {
        let (sin, cos) = grid.up_heading_rad.sin_cos();
        Self {
            center: grid.center,
            sin,
            cos,
            half_extent_m: grid.extent_m / 2.0,
            cell_m: grid.extent_m / grid.cells as f32,
            cells: grid.cells,
        }
    }

    #[inline]
    fn cell_of(&self, x: f32, y: f32) -> Option<usize> {
        let (dx, dy) = (x - self.center.x, y - self.center.y);
        let forward = dx * self.cos + dy * self.sin;
        let right = dx * self.sin - dy * self.cos;
        if !(forward.is_finite() && right.is_finite()) {
            return None;
        }
        let col = floor_to_i32((right + self.half_extent_m) / self.cell_m);
        let row = floor_to_i32((self.half_extent_m - forward) / self.cell_m);
        let n = self.cells as i32;
        (col >= 0 && row >= 0 && col < n && row < n)
            .then(|| row as usize * self.cells + col as usize)
    }
}

/// What a projection shows; every cell is 0 or 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ProjectionKind {
    /// Surfaces of objects or structure between `min_height_m` and `max_height_m`.
    Occupancy {
        /// Lowest height that counts (above the floor).
        min_height_m: f32,
        /// Highest height that counts.
        max_height_m: f32,
    },
    /// Objects tried with the affordance whose label is success.
    InteractedSuccess(Affordance),
    /// Objects tried with the affordance whose label is failure.
    InteractedFailure(Affordance),
    /// Objects never tried with the affordance.
    NotInteracted(Affordance),
}

impl Map {
    /// Rasterises `kind` onto `grid` (row-major, `cells × cells`, values 0 / 1).
    /// For several projections of one map state, gather [`Map::surface_points`]
    /// once and project those.
    pub fn project(&self, kind: ProjectionKind, grid: &GridSpec) -> Vec<f32> {
        self.surface_points().project(kind, grid)
    }

    /// World-frame surface points of the background and of every object not
    /// held (observed voxels within one voxel of the surface).
    pub fn surface_points(&self) -> SurfacePoints<'_> {
        let background = self.background();
        let objects = self
            .objects()
            .values()
            .filter(|o| !o.held)
            .map(|object| {
                let points = object
                    .volume
                    .near_surface_voxels(object.volume.voxel_size_m)
                    .into_iter()
                    .map(|(p, _)| object.t_world_object * p)
                    .collect();
                (object, points)
            })
            .collect();
        SurfacePoints {
            background: background
                .near_surface_voxels(background.voxel_size_m)
                .into_iter()
                .map(|(p, _)| p)
                .collect(),
            objects,
        }
    }
}

/// The map's surface as world-frame points, gathered once (the voxel scan is
/// the expensive part) and rasterised into any number of projections.
#[derive(Debug, Clone)]
pub struct SurfacePoints<'a> {
    background: Vec<Point3<f32>>,
    objects: Vec<(&'a MapObject, Vec<Point3<f32>>)>,
}

impl SurfacePoints<'_> {
    /// Rasterises `kind` onto `grid` (row-major, `cells × cells`, values 0 / 1).
    pub fn project(&self, kind: ProjectionKind, grid: &GridSpec) -> Vec<f32> {
        let mut out = vec![0.0; grid.cells * grid.cells];
        let heights = match kind {
            ProjectionKind::Occupancy {
                min_height_m,
                max_height_m,
            } => Some(min_height_m..=max_height_m),
            _ => None,
        };
        let locator = CellLocator::new(grid);
        let mut mark = |points: &[Point3<f32>]| {
            for p in points {
                if heights.as_ref().is_some_and(|h| !h.contains(&p.z)) {
                    continue;
                }
                if let Some(c) = locator.cell_of(p.x, p.y) {
                    out[c] = 1.0;
                }
            }
        };
        if heights.is_some() {
            mark(&self.background);
        }
        for (object, points) in &self.objects {
            let include = match kind {
                ProjectionKind::Occupancy { .. } => true,
                ProjectionKind::InteractedSuccess(a) => {
                    object.labels.interacted(a) && object.labels.label(a) == Some(true)
                }
                ProjectionKind::InteractedFailure(a) => {
                    object.labels.interacted(a) && object.labels.label(a) == Some(false)
                }
                ProjectionKind::NotInteracted(a) => !object.labels.interacted(a),
            };
            if include {
                mark(points);
            }
        }
        out
    }
}

/// Marks the cells of visited positions (world x / y) on `grid`.
pub fn visited(positions: &[Point2<f32>], grid: &GridSpec) -> Vec<f32> {
    let mut out = vec![0.0; grid.cells * grid.cells];
    let locator = CellLocator::new(grid);
    for p in positions {
        if let Some(c) = locator.cell_of(p.x, p.y) {
            out[c] = 1.0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn egocentric_grids_rotate_with_the_heading() {
        let north = GridSpec {
            center: Point2::new(0.0, 0.0),
            up_heading_rad: std::f32::consts::FRAC_PI_2,
            extent_m: 2.0,
            cells: 4,
        };
        // A point 0.75 m ahead (+y) lands in the top row, middle-right column boundary.
        assert_eq!(north.cell_of(0.1, 0.75), Some(2));
        let east = GridSpec {
            up_heading_rad: 0.0,
            ..north
        };
        // The same point seen facing +x is to the agent's left.
        assert_eq!(east.cell_of(0.1, 0.75), Some(4));
        assert_eq!(north.cell_of(5.0, 0.0), None);
    }
}
