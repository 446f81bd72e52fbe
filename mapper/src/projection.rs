//! 2-D projections of the map onto the floor plane (world z is up), at any
//! extent and resolution, world-aligned or egocentric.

use nalgebra::{Point2, Point3};

use crate::labels::Affordance;
use crate::map::Map;

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
        let (dx, dy) = (x - self.center.x, y - self.center.y);
        let (s, c) = self.up_heading_rad.sin_cos();
        let forward = dx * c + dy * s;
        let right = dx * s - dy * c;
        let cell_m = self.extent_m / self.cells as f32;
        let col = ((right + self.extent_m / 2.0) / cell_m).floor();
        let row = ((self.extent_m / 2.0 - forward) / cell_m).floor();
        let n = self.cells as f32;
        (col >= 0.0 && row >= 0.0 && col < n && row < n)
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
    pub fn project(&self, kind: ProjectionKind, grid: &GridSpec) -> Vec<f32> {
        let mut out = vec![0.0; grid.cells * grid.cells];
        let mut mark = |p: Point3<f32>| {
            if let Some(c) = grid.cell_of(p.x, p.y) {
                out[c] = 1.0;
            }
        };
        if let ProjectionKind::Occupancy {
            min_height_m,
            max_height_m,
        } = kind
        {
            let background = self.background();
            for (p, _) in background.near_surface_voxels(background.voxel_size_m) {
                if (min_height_m..=max_height_m).contains(&p.z) {
                    mark(p);
                }
            }
        }
        for object in self.objects().values().filter(|o| !o.held) {
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
            if !include {
                continue;
            }
            for (p, _) in object
                .volume
                .near_surface_voxels(object.volume.voxel_size_m)
            {
                let w = object.t_world_object * p;
                if let ProjectionKind::Occupancy {
                    min_height_m,
                    max_height_m,
                } = kind
                {
                    if !(min_height_m..=max_height_m).contains(&w.z) {
                        continue;
                    }
                }
                mark(w);
            }
        }
        out
    }
}

/// Marks the cells of visited positions (world x / y) on `grid`.
pub fn visited(positions: &[Point2<f32>], grid: &GridSpec) -> Vec<f32> {
    let mut out = vec![0.0; grid.cells * grid.cells];
    for p in positions {
        if let Some(c) = grid.cell_of(p.x, p.y) {
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
