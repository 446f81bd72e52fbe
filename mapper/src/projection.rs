//! 2-D projections of the map onto the floor plane (world z is up), at any
//! extent and resolution, world-aligned or egocentric.

use nalgebra::{Point2, Point3};

use crate::labels::Affordance;
use crate::layer::{
    band_holds, floor_to_i32, Band, BlockIndex, Layer, SurfaceMask, VoxelIndex, MAX_BANDS,
};
use crate::layer::{BLOCK_EDGE, BLOCK_VOXELS, LEVEL_VOXELS};
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

    /// False when the box from `lo` to `hi` (floor plane) lies wholly
    /// outside the circle around the grid (so outside the grid, whatever
    /// its heading).
    fn may_cover(&self, lo: [f32; 2], hi: [f32; 2]) -> bool {
        let centre = [self.center.x, self.center.y];
        let gap = |a: usize| (lo[a] - centre[a]).max(centre[a] - hi[a]).max(0.0);
        let reach = self.half_extent_m * std::f32::consts::SQRT_2;
        gap(0).powi(2) + gap(1).powi(2) <= reach * reach
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

    /// The surface points of the background and of every placed object
    /// ([`crate::MapObject::is_placed`]; the centres of observed voxels
    /// within one voxel of the surface). Each block keeps which of its
    /// voxels those are until its voxels change
    /// ([`crate::Layer::surface_mask`]), and each object's layer their
    /// centres until any of its blocks may change
    /// ([`crate::Layer::surface_centres`]), and moved into the world, as
    /// voxel columns with the heights they reach, until it moves or its
    /// surface changes (its layer's footprint, made as they are first
    /// rasterised); the background's (whose frame is the world's) stay as
    /// those masks, so that occupancy marks each of a block's columns
    /// once, however many voxels it holds.
    pub fn surface_points(&self) -> SurfacePoints<'_> {
        let background = self.background();
        let background_blocks = background
            .block_indices()
            .into_iter()
            .filter_map(|b| background.surface_mask(b).map(|m| (b, m)))
            .filter(|(_, m)| m.count() > 0)
            .collect();
        let objects = (self.objects().values())
            .filter(|o| o.is_placed())
            .filter_map(PointGroup::new)
            .collect();
        SurfacePoints {
            background: background_blocks,
            background_layer: background,
            objects,
        }
    }
}

/// One placed object with surface points (rasterised from its layer's
/// footprint, [`crate::Layer::surface_footprint`]) and a box on the floor
/// plane that holds them, so that a grid can skip the whole object.
#[derive(Debug, Clone)]
struct PointGroup<'a> {
    object: &'a MapObject,
    lo: [f32; 2],
    hi: [f32; 2],
}

impl<'a> PointGroup<'a> {
    /// `None` for an object without surface points.
    fn new(object: &'a MapObject) -> Option<Self> {
        // Every surface voxel's centre lies in the layer's blocks: the
        // world box of those blocks' eight corners holds them all.
        let (min, max) = object
            .volume
            .block_bounds()
            .filter(|_| !object.volume.surface_centres().is_empty())?;
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for corner in 0..8 {
            let pick = |bit: usize, a: f32, b: f32| if corner >> bit & 1 == 0 { a } else { b };
            let c = object.t_world_object
                * Point3::new(
                    pick(0, min.x, max.x),
                    pick(1, min.y, max.y),
                    pick(2, min.z, max.z),
                );
            lo = [lo[0].min(c.x), lo[1].min(c.y)];
            hi = [hi[0].max(c.x), hi[1].max(c.y)];
        }
        Some(Self { object, lo, hi })
    }
}

/// The map's surface, gathered once (the voxel scan is the expensive part)
/// and rasterised into any number of projections.
#[derive(Debug, Clone)]
pub struct SurfacePoints<'a> {
    /// The background's blocks that hold surface voxels, in index order,
    /// with which voxels those are (the background's frame is the world's).
    background: Vec<(BlockIndex, SurfaceMask)>,
    /// The background's layer (for its voxels' centres).
    background_layer: &'a Layer,
    /// Each placed object with surface points.
    objects: Vec<PointGroup<'a>>,
}

impl SurfacePoints<'_> {
    /// Rasterises `kind` onto `grid` (row-major, `cells × cells`, values 0 / 1).
    pub fn project(&self, kind: ProjectionKind, grid: &GridSpec) -> Vec<f32> {
        self.project_all(&[(kind, *grid)])
            .pop()
            .expect("one projection per request")
    }

    /// Rasterises every `(kind, grid)` request in one pass over the points,
    /// in the order asked: a point's cell is worked out once per distinct
    /// grid, however many projections share that grid.
    ///
    /// # Panics
    ///
    /// If the occupancy requests ask for more than 64 distinct heights
    /// ([`SurfacePoints::project_all_into`]).
    pub fn project_all(&self, requests: &[(ProjectionKind, GridSpec)]) -> Vec<Vec<f32>> {
        let mut out: Vec<Vec<f32>> = (requests.iter())
            .map(|(_, grid)| vec![0.0; grid.cells * grid.cells])
            .collect();
        let mut planes: Vec<&mut [f32]> = out.iter_mut().map(Vec::as_mut_slice).collect();
        self.project_all_into(requests, &mut planes, 1.0);
        out
    }

    /// [`SurfacePoints::project_all`] into planes the caller holds (one per
    /// request, in order, each `cells × cells` of its request's grid; every
    /// cell is written: `marked` where the projection shows a point,
    /// `T::default()` elsewhere), so that a caller assembling many planes
    /// into one buffer copies none of them, in the values it keeps (the
    /// actor's state keeps bytes).
    ///
    /// # Panics
    ///
    /// If `planes` and `requests` differ in number, a plane in size from
    /// its grid, or the occupancy requests ask for more than 64 distinct
    /// heights (an object's kept footprint has a bit per height band).
    pub fn project_all_into<T: Copy + Default>(
        &self,
        requests: &[(ProjectionKind, GridSpec)],
        planes: &mut [&mut [T]],
        marked: T,
    ) {
        assert_eq!(planes.len(), requests.len(), "one plane per request");
        for (plane, (_, grid)) in planes.iter().zip(requests) {
            assert_eq!(
                plane.len(),
                grid.cells * grid.cells,
                "a plane of its grid's size"
            );
        }
        let mut raster = Raster::new(requests);
        raster.mark_background(self.background_layer, &self.background);
        for group in &self.objects {
            raster.mark_object(group);
        }
        raster.write_planes(planes, marked);
    }
}

/// Whether projections of `kind` show `object`'s surface.
fn shows(object: &MapObject, kind: ProjectionKind) -> bool {
    match kind {
        ProjectionKind::Occupancy { .. } => true,
        ProjectionKind::InteractedSuccess(a) => {
            object.labels.interacted(a) && object.labels.label(a) == Some(true)
        }
        ProjectionKind::InteractedFailure(a) => {
            object.labels.interacted(a) && object.labels.label(a) == Some(false)
        }
        ProjectionKind::NotInteracted(a) => !object.labels.interacted(a),
    }
}

/// Up to 64 projections onto one grid, rasterised together: a cell holds one
/// bit per projection.
struct Slot {
    grid: GridSpec,
    locator: CellLocator,
    /// `(request index, kind)` of each bit.
    planes: Vec<(usize, ProjectionKind)>,
    /// Per band of [`Raster::bands`], the bits of this grid's occupancy
    /// projections of that band.
    band_bits: Vec<u64>,
    bits: Vec<u64>,
}

/// Projections being rasterised together, grouped by grid.
struct Raster {
    slots: Vec<Slot>,
    /// The occupancy projections' distinct height bands, in request order.
    bands: Vec<Band>,
}

impl Raster {
    /// # Panics
    ///
    /// With occupancy projections of more than [`MAX_BANDS`]
    /// distinct heights.
    fn new(requests: &[(ProjectionKind, GridSpec)]) -> Self {
        let mut slots: Vec<Slot> = Vec::new();
        let mut bands: Vec<Band> = Vec::new();
        let mut occupancy = Vec::new();
        for (index, (kind, grid)) in requests.iter().enumerate() {
            let slot = slots
                .iter()
                .position(|s| s.grid == *grid && s.planes.len() < 64);
            let slot = slot.unwrap_or_else(|| {
                slots.push(Slot {
                    grid: *grid,
                    locator: CellLocator::new(grid),
                    planes: Vec::new(),
                    band_bits: Vec::new(),
                    bits: vec![0; grid.cells * grid.cells],
                });
                slots.len() - 1
            });
            if let ProjectionKind::Occupancy {
                min_height_m,
                max_height_m,
            } = *kind
            {
                let band = [min_height_m, max_height_m];
                let known = bands.iter().position(|b| *b == band);
                let band = known.unwrap_or_else(|| {
                    bands.push(band);
                    bands.len() - 1
                });
                occupancy.push((slot, band, 1u64 << slots[slot].planes.len()));
            }
            slots[slot].planes.push((index, *kind));
        }
        assert!(
            bands.len() <= MAX_BANDS,
            "occupancy projections of at most {} distinct heights",
            MAX_BANDS
        );
        for slot in &mut slots {
            slot.band_bits = vec![0; bands.len()];
        }
        for (slot, band, bit) in occupancy {
            slots[slot].band_bits[band] |= bit;
        }
        Self { slots, bands }
    }

    /// Marks the background's surface voxels in every occupancy projection
    /// whose heights hold them, a column of a block at a time (a voxel's
    /// cell depends on its centre's x and y alone): a wall's column of
    /// eight voxels is one cell lookup, not eight.
    fn mark_background(&mut self, layer: &Layer, blocks: &[(BlockIndex, SurfaceMask)]) {
        let mut columns: Vec<(u64, u64)> = Vec::new();
        for slot in &mut self.slots {
            // Each band's bits on this grid, where it has any.
            let occupancy: Vec<(u64, Band)> = (slot.band_bits.iter().zip(&self.bands))
                .filter(|(&bits, _)| bits != 0)
                .map(|(&bits, &band)| (bits, band))
                .collect();
            if occupancy.is_empty() {
                continue;
            }
            for &(b, mask) in blocks {
                let first = layer.voxel_center(VoxelIndex::join(b, 0));
                let last = layer.voxel_center(VoxelIndex::join(b, BLOCK_VOXELS - 1));
                if !slot.locator.may_cover([first.x, first.y], [last.x, last.y]) {
                    continue;
                }
                // Each band's bits with the block's columns that hold a
                // voxel within its heights.
                columns.clear();
                columns.extend(occupancy.iter().map(|&(bits, band)| {
                    let mut levels = 0u8;
                    for z in 0..BLOCK_EDGE as usize {
                        let centre = layer.voxel_center(VoxelIndex::join(b, z * LEVEL_VOXELS));
                        levels |= u8::from(band_holds(band, centre.z)) << z;
                    }
                    (bits, mask.columns(levels))
                }));
                let mut any = columns.iter().fold(0, |any, (_, c)| any | c);
                while any != 0 {
                    let column = any.trailing_zeros() as usize;
                    any &= any - 1;
                    let centre = layer.voxel_center(VoxelIndex::join(b, column));
                    if let Some(c) = slot.locator.cell_of(centre.x, centre.y) {
                        for (bit, cols) in &columns {
                            if cols >> column & 1 == 1 {
                                slot.bits[c] |= bit;
                            }
                        }
                    }
                }
            }
        }
    }

    /// Marks an object's surface in every projection that [`shows`] it:
    /// occupancy (which shows every object) only where a point lies within
    /// its heights, the label kinds wherever it stands. The object's
    /// footprint for its pose and these requests' bands
    /// ([`crate::Layer::surface_footprint`], kept by its layer while
    /// neither changes) holds each voxel column's world x and y and the
    /// bands its points reach: a column is one cell lookup per grid.
    fn mark_object(&mut self, group: &PointGroup<'_>) {
        // Per grid that may hold the object: the bits it shows everywhere
        // and, per band, the bits of its occupancy projections of that band.
        let mut marking = Vec::new();
        for slot in &mut self.slots {
            if !slot.locator.may_cover(group.lo, group.hi) {
                continue;
            }
            let always = (slot.planes.iter().enumerate())
                .filter(|(_, (_, kind))| !matches!(kind, ProjectionKind::Occupancy { .. }))
                .filter(|(_, (_, kind))| shows(group.object, *kind))
                .fold(0u64, |always, (bit, _)| always | 1 << bit);
            if always != 0 || slot.band_bits.iter().any(|&bits| bits != 0) {
                marking.push((&mut slot.bits, &slot.locator, always, &slot.band_bits));
            }
        }
        if marking.is_empty() {
            return;
        }
        let object = group.object;
        let footprint = (object.volume).surface_footprint(&object.t_world_object, &self.bands);
        for column in footprint.columns() {
            for (bits, locator, always, band_bits) in &mut marking {
                let Some(c) = locator.cell_of(column.x, column.y) else {
                    continue;
                };
                let mut mask = *always;
                let mut reached = column.bands;
                while reached != 0 {
                    mask |= band_bits[reached.trailing_zeros() as usize];
                    reached &= reached - 1;
                }
                bits[c] |= mask;
            }
        }
    }

    /// Writes each projection into its request's plane: `marked` where it
    /// shows a point, the default elsewhere.
    fn write_planes<T: Copy + Default>(self, planes: &mut [&mut [T]], marked: T) {
        for slot in self.slots {
            for (bit, (index, _)) in slot.planes.iter().enumerate() {
                for (cell, bits) in planes[*index].iter_mut().zip(&slot.bits) {
                    *cell = if bits >> bit & 1 == 1 {
                        marked
                    } else {
                        T::default()
                    };
                }
            }
        }
    }
}

/// Marks the cells of visited positions (world x / y) on `grid`.
pub fn visited(positions: &[Point2<f32>], grid: &GridSpec) -> Vec<f32> {
    let mut out = vec![0.0; grid.cells * grid.cells];
    mark_visited(positions, grid, &mut out, 1.0);
    out
}

/// [`visited`] into a plane the caller holds (`cells × cells`, every cell
/// written: `marked` where a position lies, `T::default()` elsewhere).
pub fn mark_visited<T: Copy + Default>(
    positions: &[Point2<f32>],
    grid: &GridSpec,
    plane: &mut [T],
    marked: T,
) {
    plane.fill(T::default());
    let locator = CellLocator::new(grid);
    for p in positions {
        if let Some(c) = locator.cell_of(p.x, p.y) {
            plane[c] = marked;
        }
    }
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
