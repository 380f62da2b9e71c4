//! The scene's medium: one record (a box, its scale and marching step, and references to
//! its density, emission and albedo, constants or grids in the material data or θ), the
//! BVH of its boundary mesh where it has one, and its majorant grid. Its parameters: the
//! density, the emission and the albedo, of any grid size.

use super::{Feature, Upload};
use crate::gpu::{self, Buffer, ComputePipeline, Recorder, SpecValue};
use crate::kernels::MajorantPush;
use crate::render::{texel_buffer, ParamSlot};
use crate::scene::media::{grid_dims, MAX_STEPS};
use crate::scene::{Medium, MediumBoundary, ParamTarget};
use crate::shared::{MediumRecord, ValueRef};
use crate::tensor::ParamValue;

/// How far a scattering medium's majorant lies above the most its extinction can be. The
/// tracking costs lookups in proportion to the majorant; the finite-difference kernels'
/// second state is weighted (σ̄ − σ_1)/(σ̄ − σ_0) at each null collision, whose spread
/// grows as σ̄ approaches σ: 20 % above keeps a 1 % change of the density to a 5 % weight.
pub const MAJORANT_MARGIN: f32 = 1.2;

pub struct Media {
    buffer: Buffer,
    present: bool,
    /// Whether the medium scatters: the scene's trace kernels are then the `_scatter`
    /// builds ([`crate::render::GpuScene::kernel`]).
    pub scattering: bool,
    /// A scattering medium whose density is optimised: the pass that sets its majorant
    /// grid from θ before each pass that tracks it ([`Media::record_majorant`]).
    majorant: Option<(ComputePipeline, MajorantPush)>,
    /// The majorant grid's cells per axis (zeros where the medium has none).
    pub cells: [u32; 3],
    /// Whether the medium has a boundary mesh (`MEDIUM_BOUNDARY`).
    boundary: bool,
    /// The last majorant pass recorded: its recording, the θ and previous θ it read, and
    /// when it wrote the record ([`Media::record_majorant`]).
    last_pass: std::cell::Cell<Option<LastPass>>,
}

/// See [`Media::last_pass`].
#[derive(Clone, Copy, PartialEq)]
struct LastPass {
    recording: u64,
    theta: u64,
    theta_prev: u64,
    wrote: Option<u64>,
}

/// A majorant cell's side, in voxels of the density grid: each cell bounds the
/// extinction over 8³ voxels (and the lookups' neighbours), so that tracking takes few
/// tentative collisions where the medium is thin and none where it is empty. Finer cells
/// cost more steps from cell to cell than they save on the bundled cloud.
pub const MAJORANT_CELL_VOXELS: u32 = 8;

/// The majorant grid's cells per axis over a density grid of `dims` voxels.
pub fn majorant_cells(dims: [u32; 3]) -> [u32; 3] {
    dims.map(|n| n.div_ceil(MAJORANT_CELL_VOXELS).max(1))
}

/// The voxels, first and last along one axis, that a trilinear lookup anywhere in cell
/// `c` of `cells` weighs, in a grid of `n` voxels: the cell spans voxel coordinates
/// [c n / cells, (c + 1) n / cells], and a lookup at x weighs the voxels whose centres
/// bracket it, floor(x − ½) and the next (clamped to the grid). In integers, as
/// glsl/majorant.comp computes it.
pub fn cell_voxels(c: u32, cells: u32, n: u32) -> (u32, u32) {
    let (c, cells, n) = (c as i64, cells as i64, n as i64);
    let lo = ((2 * c * n - cells) / (2 * cells)).max(0);
    let hi = ((2 * (c + 1) * n - cells) / (2 * cells) + 1).min(n - 1);
    (lo as u32, hi as u32)
}

/// The deepest inner node of a boundary's BVH: its traversal's stack
/// (`BOUNDARY_STACK` in glsl/lib/media.glsl) holds one entry per level.
pub const BOUNDARY_BVH_DEPTH: u32 = 16;

/// A boundary mesh as the kernels read it, in 32-bit words (whole texels): a texel of its
/// BVH's node and triangle counts, the nodes, then the triangles in leaf order.
pub fn boundary_words(b: &MediumBoundary) -> Vec<u32> {
    let bvh = crate::bvh::build_with_depth_limit(&b.positions, &b.indices, BOUNDARY_BVH_DEPTH);
    let mut words = vec![bvh.nodes.len() as u32, bvh.triangles.len() as u32, 0, 0];
    words.extend_from_slice(bytemuck::cast_slice(&bvh.nodes));
    words.extend_from_slice(bytemuck::cast_slice(&bvh.triangles));
    words
}

/// The threads of a workgroup of the majorant pass (glsl/majorant.comp).
const MAJORANT_REDUCE_THREADS: u32 = 64;

/// The record's `majorant_cells` word for a grid of `cells`.
pub fn pack_cells(cells: [u32; 3]) -> u32 {
    cells[0] | cells[1] << 10 | cells[2] << 20
}

/// The majorant cells a ray crosses per unit length, on average over directions: half of
/// the cells per unit length along each axis, summed (the mean |cos| to an axis is ½).
pub fn crossings_per_length(cells: [u32; 3], min: [f32; 3], max: [f32; 3]) -> f32 {
    (0..3).map(|a| 0.5 * cells[a] as f32 / (max[a] - min[a])).sum()
}

/// What a step from one majorant cell to the next costs, in tentative collisions (their
/// lookups), roughly. Walking the bundled cloud's grid took 1.28× the time of one
/// majorant at a constant density (nothing to save), 0.94× at its true density and 0.65×
/// at 5 times it.
pub const CELL_STEP_COST: f32 = 0.5;

/// Whether tracking walks majorant grid `grid` cell by cell rather than taking its largest
/// cell over the whole box: where the tentative collisions it saves per unit length (its
/// largest cell above its mean cell) outweigh its steps' cost there (`walk_cost`:
/// [`CELL_STEP_COST`] × [`crossings_per_length`]). A grid of equal cells saves nothing (a
/// constant density, the start of most optimisations); a sparse or thick medium saves
/// many. The majorant pass decides the same.
pub fn walks_grid(grid: &[f32], walk_cost: f32) -> bool {
    let most = grid.iter().copied().fold(0.0f32, f32::max);
    let mean = grid.iter().sum::<f32>() / grid.len().max(1) as f32;
    most - mean >= walk_cost
}

/// The majorant grid of a density grid of `dims` voxels (x fastest): per cell,
/// `factor` times the largest density that its lookups weigh.
pub fn majorant_grid(density: &[f32], dims: [u32; 3], factor: f32) -> Vec<f32> {
    let cells = majorant_cells(dims);
    let mut out = Vec::with_capacity(cells.iter().product::<u32>() as usize);
    for cz in 0..cells[2] {
        for cy in 0..cells[1] {
            for cx in 0..cells[0] {
                let [(x0, x1), (y0, y1), (z0, z1)] = [(cx, 0), (cy, 1), (cz, 2)].map(|(c, a)| cell_voxels(c, cells[a], dims[a]));
                let mut most = 0.0f32;
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        for x in x0..=x1 {
                            most = most.max(density[((z * dims[1] + y) * dims[0] + x) as usize]);
                        }
                    }
                }
                out.push(factor * most);
            }
        }
    }
    out
}

/// A grid's reference and depth: the scene's value in the material data, or its slot of θ.
fn grid_ref(up: &mut Upload, slot: Option<&ParamSlot>, value: &ParamValue) -> (ValueRef, u32) {
    let (shape, r) = match slot {
        Some(s) => (s.shape, ValueRef { offset: s.offset as i32, width: 0, height: 0, flags: ValueRef::IN_THETA }),
        None => (value.shape, up.data.constant(&value.data)),
    };
    if shape.is_constant() {
        return (r, 0);
    }
    let [x, y, z] = grid_dims(shape).map(|d| d as u32);
    (ValueRef { width: x, height: y, ..r }, z)
}

/// How a scattering medium is tracked: against one majorant over its box, or a grid of
/// them (a density grid that no fixed `majorant` key bounds), set from θ by a pass where
/// the density is optimised.
struct Tracking {
    /// The majorant over the box (the grid's largest cell where it has one): 0 for a
    /// medium that does not scatter.
    majorant: f32,
    cells: [u32; 3],
    grid: Vec<f32>,
    /// Whether the kernels walk the grid (`walks_grid`), until the pass decides again.
    walk: bool,
    pass: Option<(ComputePipeline, MajorantPush)>,
}

impl Tracking {
    /// `grid_word`: where the majorant grid starts in the medium's buffer, in words.
    fn build(up: &Upload, m: &Medium, density_slot: Option<&ParamSlot>, grid_word: u32) -> gpu::Result<Tracking> {
        // Above the most the extinction can be: the fixed bound, the density parameter's
        // range, or the density's values.
        let factor = MAJORANT_MARGIN * m.scale;
        let density_bound = match (m.majorant, density_slot) {
            (Some(b), _) => b,
            (None, Some(slot)) => slot.range[1],
            (None, None) => m.density.data.iter().copied().fold(0.0f32, f32::max),
        };
        let majorant = if m.scatters() { factor * density_bound.max(0.0) } else { 0.0 };
        let none = Tracking { majorant, cells: [0; 3], grid: Vec::new(), walk: false, pass: None };
        let shape = match (m.scatters(), m.majorant, density_slot) {
            (true, None, Some(slot)) => slot.shape,
            (true, None, None) if !m.density.shape.is_constant() => m.density.shape,
            _ => return Ok(none),
        };
        let dims = grid_dims(shape).map(|d| d as u32);
        let cells = majorant_cells(dims);
        let walk_cost = CELL_STEP_COST * crossings_per_length(cells, m.min, m.max);
        let Some(slot) = density_slot else {
            let grid = majorant_grid(&m.density.data, dims, factor);
            let walk = walks_grid(&grid, walk_cost);
            return Ok(Tracking { majorant: grid.iter().copied().fold(0.0, f32::max), cells, walk, grid, pass: None });
        };
        // An optimised density moves: its grid follows θ (the range's bound, over the box,
        // holds until the first pass sets it).
        let push = MajorantPush {
            offset: slot.offset as u32,
            dims,
            cells,
            grid_word,
            record_word: (std::mem::offset_of!(MediumRecord, majorant) / 4) as u32,
            factor,
            walk_cost,
            stage: 0,
            states: 2,
        };
        let pass = Some((ComputePipeline::new(up.ctx, "majorant", &[])?, push));
        Ok(Tracking { majorant, cells, grid: vec![majorant; cells.iter().product::<u32>() as usize], walk: false, pass })
    }
}

impl Media {
    pub fn build(up: &mut Upload) -> gpu::Result<Media> {
        let (scene, layout) = (up.scene, up.layout);
        let mut record = MediumRecord::default();
        let present = !scene.media.is_empty();
        let scattering = scene.media.iter().any(|m| m.scatters());
        let (mut cells, mut grid, mut majorant_pass) = ([0u32; 3], Vec::new(), None);
        let mut boundary = Vec::new();
        if let Some(m) = scene.media.first() {
            let (density, density_depth) = grid_ref(up, layout.slot(ParamTarget::MediumDensity { medium: 0 }), &m.density);
            let (emission, emission_depth) = grid_ref(up, layout.slot(ParamTarget::MediumEmission { medium: 0 }), &m.emission);
            let (albedo, albedo_depth) = grid_ref(up, layout.slot(ParamTarget::MediumAlbedo { medium: 0 }), &m.albedo);
            // The step in voxels of the finest grid that renders: the parameters' own
            // where they are optimised.
            let mut stepped = m.clone();
            for (target, v) in [(ParamTarget::MediumDensity { medium: 0 }, &mut stepped.density), (ParamTarget::MediumEmission { medium: 0 }, &mut stepped.emission)] {
                if let Some(slot) = layout.slot(target) {
                    v.shape = slot.shape;
                }
            }
            boundary = m.boundary.as_ref().map(boundary_words).unwrap_or_default();
            let grid_word = (std::mem::size_of::<MediumRecord>() + 4 * boundary.len()) / 4;
            let tracking = Tracking::build(up, m, layout.slot(ParamTarget::MediumDensity { medium: 0 }), grid_word as u32)?;
            record = MediumRecord {
                box_min: m.min,
                step: stepped.world_step(),
                box_max: m.max,
                scale: m.scale,
                density,
                emission,
                density_depth,
                emission_depth,
                max_steps: MAX_STEPS,
                albedo_depth,
                albedo,
                g: m.g,
                majorant: tracking.majorant,
                majorant_cells: if tracking.walk { pack_cells(tracking.cells) } else { 0 },
                boundary_texels: (boundary.len() / 4) as u32,
            };
            (cells, grid, majorant_pass) = (tracking.cells, tracking.grid, tracking.pass);
        }
        let mut words: Vec<u32> = bytemuck::cast_slice(&[record]).to_vec();
        words.extend_from_slice(&boundary);
        words.extend(grid.iter().flat_map(|v| [v.to_bits(), 0, 0, 0]));
        let buffer = texel_buffer(up.ctx, "media", &words)?;
        Ok(Media { buffer, present, scattering, majorant: majorant_pass, cells, boundary: !boundary.is_empty(), last_pass: Default::default() })
    }

    /// Records the pass that sets a scattering medium's majorant grid from the density in
    /// `theta` and `theta_prev` (the buffers a tracking pass binds as its θ and previous
    /// θ: the same one twice for a single state), where the density is optimised. Every
    /// pass that tracks the medium follows one (`render::record_samples`), so that the
    /// majorant holds whoever wrote θ, and the primal and adjoint passes of one θ track
    /// against the same one.
    pub fn record_majorant(&self, rec: &mut Recorder, theta: &Buffer, theta_prev: &Buffer) -> gpu::Result<()> {
        let Some((pipeline, push)) = &self.majorant else { return Ok(()) };
        // Once per θ: a pass that the recording has already made for these buffers, with
        // neither written since and the record untouched, would write what it wrote (the
        // sensors of one iteration share it).
        let (id, id_prev) = (theta.id(), theta_prev.id());
        if let Some(last) = self.last_pass.get() {
            let unchanged = |b: &Buffer| rec.last_write(b) < last.wrote;
            if last == (LastPass { recording: rec.recording(), theta: id, theta_prev: id_prev, wrote: rec.last_write(&self.buffer) }) && unchanged(theta) && unchanged(theta_prev) {
                return Ok(());
            }
        }
        let group = pipeline.bind(&[("Theta", theta), ("ThetaPrev", theta_prev), ("Record", &self.buffer)])?;
        let push = MajorantPush { states: if id == id_prev { 1 } else { 2 }, ..*push };
        rec.dispatch_linear(pipeline, &group, &push, self.cells.iter().map(|&c| c as u64).product())?;
        // The second stage reads the cells the first wrote: their largest, and whether the
        // kernels walk them.
        rec.dispatch(pipeline, &group, &MajorantPush { stage: 1, ..push }, [MAJORANT_REDUCE_THREADS, 1, 1])?;
        self.last_pass.set(Some(LastPass { recording: rec.recording(), theta: id, theta_prev: id_prev, wrote: rec.last_write(&self.buffer) }));
        Ok(())
    }
}

impl Feature for Media {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Media", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        vec![
            ("HAS_MEDIA", SpecValue::Bool(self.present)),
            ("MAJORANT_GRID", SpecValue::Bool(self.cells != [0; 3])),
            ("MEDIUM_BOUNDARY", SpecValue::Bool(self.boundary)),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::unit_hash as hashed;
    use crate::scene::media::trilinear;
    use crate::tensor::Shape;

    /// Each cell of a majorant grid bounds every trilinear lookup in its part of the box,
    /// faces included, for grids whose sides the cells divide and grids they do not.
    #[test]
    fn each_majorant_cell_bounds_the_lookups_in_it() {
        for (case, dims) in [[4u32, 4, 4], [20, 14, 9], [1, 3, 17], [27, 1, 2], [32, 32, 32]].into_iter().enumerate() {
            let n = dims.iter().product::<u32>();
            // Sparse values: most voxels 0, so that a cell missing a neighbour shows.
            let data: Vec<f32> = (0..n as u64).map(|i| if hashed(i + 1000 * case as u64) < 0.2 { 1.0 + hashed(i + 77) } else { 0.0 }).collect();
            let value = ParamValue { shape: Shape::grid(dims[0], dims[1], dims[2], 1), data: data.clone() };
            let cells = majorant_cells(dims);
            let grid = majorant_grid(&data, dims, 1.0);
            assert_eq!(grid.len() as u32, cells.iter().product::<u32>());
            let fractions = [0.0f32, 1e-3, 0.25, 0.5, 0.75, 0.999, 1.0];
            for cz in 0..cells[2] {
                for cy in 0..cells[1] {
                    for cx in 0..cells[0] {
                        let bound = grid[((cz * cells[1] + cy) * cells[0] + cx) as usize];
                        for fz in fractions {
                            for fy in fractions {
                                for fx in fractions {
                                    let q = [(cx, fx, 0), (cy, fy, 1), (cz, fz, 2)].map(|(c, f, a)| (c as f32 + f) / cells[a] as f32);
                                    let v = trilinear(&value, dims.map(|d| d as usize), q)[0];
                                    assert!(v <= bound * (1.0 + 1e-6), "{dims:?}, cell {:?}: {v} at {q:?} above its bound {bound}", [cx, cy, cz]);
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// A majorant grid is tight where the density is sparse: a single voxel lights the
    /// cells whose lookups reach it (at most 2 per axis) and no others.
    #[test]
    fn a_single_voxel_lights_only_the_cells_around_it() {
        let dims = [40u32, 32, 24];
        assert_eq!(majorant_cells(dims), [5, 4, 3]);
        for voxel in [[0u32, 0, 0], [7, 4, 4], [8, 31, 23], [16, 15, 8]] {
            let mut data = vec![0.0f32; dims.iter().product::<u32>() as usize];
            data[((voxel[2] * dims[1] + voxel[1]) * dims[0] + voxel[0]) as usize] = 2.0;
            let grid = majorant_grid(&data, dims, 1.5);
            let lit = grid.iter().filter(|&&v| v > 0.0).count();
            assert!((1..=8).contains(&lit), "{voxel:?}: {lit} cells lit");
            assert!(grid.iter().all(|&v| v == 0.0 || v == 3.0), "{voxel:?}: {grid:?}");
        }
        assert_eq!(cell_voxels(0, 4, 16), (0, 4));
        assert_eq!(cell_voxels(1, 4, 16), (3, 8));
        assert_eq!(cell_voxels(3, 4, 16), (11, 15));
        assert_eq!(majorant_cells([64, 9, 1]), [8, 2, 1]);
    }
}
