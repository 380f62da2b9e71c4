//! `vkinverse bench --media`: the passes of an iteration on a medium alone, timed with
//! profiler scopes over N submissions and reported as medians.
//!
//! The scene is built in code: a [`BOX_MIN`]–[`BOX_MAX`] box of emitting and absorbing
//! medium whose density and emission are smooth random grids (sums of Gaussian blobs) of
//! N³ voxels, both optimised as N³ grids (θ of 4·N³ floats), seen by one perspective camera
//! in front of a constant environment, with no meshes and no lights. Each case (a grid side
//! and a film side) builds the engine's passes as `optimise` does and times, in one
//! submission per group:
//! - `gradient`: the proportional estimate (`trace_primal`, `loss`, `trace_adjoint`);
//! - `finite_difference`: the fused finite-difference sample (`trace_fd_primal`, `loss`,
//!   `trace_fd_adjoint`), both parameter states in one trace.
//!
//! Every pass runs one sample per pixel. Voxel lookups are counted on the host, not on the
//! device: each camera ray is clipped to the box as glsl/lib/media.glsl clips it and takes
//! the kernel's number of steps, ceil(length / step) clamped to 1..MAX_STEPS, averaged over
//! [`SUBPIXELS`]² stratified rays per pixel. A step looks up the density grid and the
//! emission grid, 8 trilinear taps each, in every parameter state the kernel carries (2 in
//! the finite-difference kernels); the adjoint kernels march each sample twice (the primal
//! replay, then the gradient replay, whose scatters of the derivatives to the same 8 voxels
//! are not counted). No scattering and no surfaces: a camera ray's march is the whole path.
//!
//! The optimiser passes are timed on a synthetic θ of 4·N³ parameters for the largest
//! grid ([`super::optimiser_bandwidth`]), against the float4 copy (`copy_vec4`).

use super::scene::Samples;
use super::{optimiser_bandwidth, OptimiserBandwidth};
use crate::engine::Engine;
use crate::error::{Error, Result};
use crate::gpu::{CommandBuffer, Profiler};
use crate::scene::media::{DEFAULT_STEP, MAX_STEPS};
use crate::scene::{ColorValue, Environment, Film, Integrator, Medium, ParamSpec, Scene, SceneParts, Sensor};
use crate::settings::RunSettings;
use crate::stats::unit_hash as hashed;
use crate::tensor::{ParamValue, Shape};
use glam::{Vec2, Vec3};
use serde::Serialize;
use std::fmt::Write as _;
use std::time::{Duration, Instant};

/// The medium's box.
pub const BOX_MIN: [f32; 3] = [-1.0, -1.0, -1.0];
pub const BOX_MAX: [f32; 3] = [1.0, 1.0, 1.0];
/// Stratified camera rays per pixel side of the host's step count.
pub const SUBPIXELS: u32 = 4;
/// Trilinear taps of one grid lookup, and the grids a step looks up (density, emission).
const TAPS: u64 = 8;
const GRIDS: u64 = 2;

/// What the medium bench measures.
#[derive(Clone, Debug)]
pub struct MediaOptions {
    /// The grids' sides (N for N³ voxels), one case each per film.
    pub grids: Vec<u32>,
    /// The films' sides (square films).
    pub films: Vec<u32>,
    /// Timed submissions of each group; the median is reported.
    pub iterations: u32,
    /// Parameters of the optimiser passes' synthetic θ [default: 4·N³ of the largest grid].
    pub optimiser_elements: Option<u64>,
    /// How long to repeat each case untimed after its first (compiling) round.
    pub warm_up: Duration,
}

impl Default for MediaOptions {
    fn default() -> Self {
        MediaOptions { grids: vec![64, 128], films: vec![64, 256], iterations: 9, optimiser_elements: None, warm_up: Duration::ZERO }
    }
}

/// One pass's median GPU time and voxel lookups.
#[derive(Clone, Debug, Serialize)]
pub struct MediaPass {
    /// gradient or finite_difference.
    pub group: String,
    /// The kernel (or `loss`, with its reduction).
    pub name: String,
    /// Samples per pixel of a tracing pass.
    pub spp: Option<u32>,
    pub median_ms: f64,
    /// Tracing passes: steps × 8 taps × 2 grids × parameter states × marches per sample,
    /// summed over the film's samples (see the module documentation).
    pub voxel_lookups: Option<u64>,
    /// `voxel_lookups` over `median_ms`.
    pub lookups_per_s: Option<f64>,
}

/// One grid size on one film.
#[derive(Clone, Debug, Serialize)]
pub struct MediaCase {
    /// Voxels along each axis of both grids.
    pub grid: u32,
    pub width: u32,
    pub height: u32,
    /// θ's floats: N³ of density and 3·N³ of emission.
    pub parameters: usize,
    /// The marching step in world units (`step` = 0.5 voxels).
    pub step: f32,
    /// The share of camera rays that cross the box.
    pub crossing_fraction: f64,
    /// Marching steps of one camera ray, over every ray (0 for those that miss the box).
    pub steps_per_ray: f64,
    /// The same over the rays that cross the box.
    pub steps_per_crossing_ray: f64,
    pub passes: Vec<MediaPass>,
    /// trace_adjoint / trace_primal at equal spp.
    pub adjoint_over_primal: f64,
    /// The finite-difference group's total over the gradient group's.
    pub fd_over_gradient: f64,
}

/// The medium bench's results.
#[derive(Clone, Debug, Serialize)]
pub struct MediaBench {
    pub device: String,
    pub iterations: u32,
    /// `LP_NUM_THREADS` as set for lavapipe (unset: Mesa's default, one per core).
    pub lp_num_threads: Option<String>,
    pub validation: bool,
    pub box_min: [f32; 3],
    pub box_max: [f32; 3],
    pub cases: Vec<MediaCase>,
    /// The fused optimiser passes on a synthetic θ (4·N³ of the largest grid by default),
    /// each against `copy` and `copy_vec4`.
    pub optimisers: OptimiserBandwidth,
}

/// Times the medium passes for every grid side × film side of `options`, then the
/// optimiser passes on a grid-sized θ.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::bench::{media_bench, MediaOptions};
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// let options = MediaOptions { grids: vec![8], films: vec![8], iterations: 1, ..MediaOptions::default() };
/// let bench = media_bench(&device, &options)?;
/// assert!(bench.cases[0].passes[0].median_ms > 0.0);
/// # Ok(())
/// # }
/// ```
pub fn media_bench(device: &crate::device::Device, options: &MediaOptions) -> Result<MediaBench> {
    let ctx = device.ctx();
    let iterations = options.iterations.max(1);
    if options.grids.is_empty() || options.films.is_empty() {
        return Err(Error::Invalid("the medium bench needs at least one grid size and one film size".into()));
    }
    // A medium's grid holds at most MAX_GRID_VOXELS = 256³ voxels.
    if let Some(n) = options.grids.iter().find(|&&n| !(2..=256).contains(&n)) {
        return Err(Error::Invalid(format!("grid side {n}: 2 to 256 voxels")));
    }
    if let Some(f) = options.films.iter().find(|&&f| f == 0 || f > 8192) {
        return Err(Error::Invalid(format!("film side {f}: 1 to 8192 pixels")));
    }
    let mut cases = Vec::new();
    for &grid in &options.grids {
        for &film in &options.films {
            cases.push(measure_case(device, grid, film, iterations, options.warm_up)?);
        }
    }
    let largest = *options.grids.iter().max().expect("checked above") as u64;
    let optimisers = optimiser_bandwidth(ctx, options.optimiser_elements.unwrap_or(4 * largest.pow(3)), iterations)?;
    Ok(MediaBench {
        device: ctx.info().name.clone(),
        iterations,
        lp_num_threads: std::env::var("LP_NUM_THREADS").ok(),
        validation: ctx.validation_enabled(),
        box_min: BOX_MIN,
        box_max: BOX_MAX,
        cases,
        optimisers,
    })
}

/// Gaussian blobs of the synthetic medium: centre, radius, density and emitted colour, in
/// the box's unit coordinates (the same for every grid size).
const BLOBS: u64 = 8;

/// The density (N³) and emission (N³ × 3) grids, x fastest: a sum of [`BLOBS`] Gaussian
/// blobs, smooth at any N; density peaks of about 1 to 3 per unit length, emission a
/// faint floor plus each blob's colour.
pub fn synthetic_grids(n: u32) -> (Vec<f32>, Vec<f32>) {
    let blobs: Vec<([f32; 3], f32, f32, [f32; 3])> = (0..BLOBS)
        .map(|b| {
            let r = |k: u64| hashed(b * 16 + k);
            ([0.2 + 0.6 * r(0), 0.2 + 0.6 * r(1), 0.2 + 0.6 * r(2)], 0.1 + 0.15 * r(3), 1.0 + 2.0 * r(4), [2.0 * r(5), 2.0 * r(6), 2.0 * r(7)])
        })
        .collect();
    let n = n as usize;
    let mut density = Vec::with_capacity(n * n * n);
    let mut emission = Vec::with_capacity(n * n * n * 3);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|i| (i as f32 + 0.5) / n as f32);
                let (mut d, mut e) = (0.0f32, [0.05f32; 3]);
                for (c, radius, amp, col) in &blobs {
                    let r2: f32 = (0..3).map(|a| (p[a] - c[a]) * (p[a] - c[a])).sum();
                    let w = (-r2 / (2.0 * radius * radius)).exp();
                    d += amp * w;
                    for k in 0..3 {
                        e[k] += col[k] * w;
                    }
                }
                density.push(d);
                emission.extend(e);
            }
        }
    }
    (density, emission)
}

/// The medium scene of one case: grids of `grid`³ voxels (optimised as such, from constant
/// starts that differ from them, so that every pixel that sees the box has an adjoint), a
/// `film`² film.
pub fn synthetic_scene(grid: u32, film: u32) -> Result<Scene> {
    let (density, emission) = synthetic_grids(grid);
    let medium = Medium {
        name: "cloud".into(),
        min: BOX_MIN,
        max: BOX_MAX,
        density: ParamValue { shape: Shape::grid(grid, grid, grid, 1), data: density },
        emission: ParamValue { shape: Shape::grid(grid, grid, grid, 3), data: emission },
        scale: 1.0,
        step: DEFAULT_STEP,
        albedo: ParamValue { shape: Shape::constant(3), data: vec![0.0; 3] },
        g: 0.0,
        majorant: None,
        formats: Default::default(),
        boundary: None,
    };
    let sensor = Sensor::looking_at(Vec3::new(1.2, 0.9, 3.4), Vec3::ZERO, Vec3::Y, 40.0).map_err(|e| Error::Invalid(e.into()))?;
    let param = |target: &str, init: f32| ParamSpec { grid: Some([grid; 3]), ..ParamSpec::new(target, &[init], [0.0, 100.0]) };
    let parts = SceneParts {
        film: Film { width: film, height: film },
        integrator: Integrator { max_depth: 2, rr_depth: 5, hide_emitters: false },
        sensors: vec![sensor],
        environment: Environment { value: ColorValue::Constant([0.4, 0.5, 0.6]), scale: 1.0 },
        media: vec![medium],
        params: vec![param("media.cloud.density", 1.0), param("media.cloud.emission", 0.2)],
        ..SceneParts::default()
    };
    Scene::from_parts(parts).map_err(|e| Error::Invalid(e.to_string()))
}

/// The part [t0, t1] of ray (o, d) in the box, as glsl/lib/media.glsl's medium_clip finds
/// it (no surface: the ray runs to 1e30).
fn clip(o: Vec3, d: Vec3) -> Option<(f32, f32)> {
    let dd = Vec3::select(d.cmpeq(Vec3::ZERO), Vec3::splat(1e-30), d);
    let ta = (Vec3::from(BOX_MIN) - o) / dd;
    let tb = (Vec3::from(BOX_MAX) - o) / dd;
    let (lo, hi) = (ta.min(tb), ta.max(tb));
    let t0 = lo.max_element().max(0.0);
    let t1 = hi.min_element().min(1e30);
    (t0 < t1).then_some((t0, t1))
}

/// The kernel's steps over a clip of length `len` (medium_march).
fn steps(len: f32, step: f32) -> u32 {
    (len / step).ceil().clamp(1.0, MAX_STEPS as f32) as u32
}

/// The camera rays' steps through the box: the sum over pixels of each pixel's mean over
/// SUBPIXELS² stratified rays, and the share of rays that cross the box.
fn march_steps(sensor: &Sensor, width: u32, height: u32, step: f32) -> (f64, f64) {
    let aspect = width as f32 / height as f32;
    let (mut total, mut crossing) = (0u64, 0u64);
    for y in 0..height {
        for x in 0..width {
            for j in 0..SUBPIXELS {
                for i in 0..SUBPIXELS {
                    let sub = Vec2::new((i as f32 + 0.5) / SUBPIXELS as f32, (j as f32 + 0.5) / SUBPIXELS as f32);
                    let ndc = Vec2::new((x as f32 + sub.x) / width as f32 * 2.0 - 1.0, 1.0 - (y as f32 + sub.y) / height as f32 * 2.0);
                    let (o, d) = sensor.ray(ndc, aspect);
                    if let Some((t0, t1)) = clip(o, d) {
                        total += steps(t1 - t0, step) as u64;
                        crossing += 1;
                    }
                }
            }
        }
    }
    let per_pixel = (SUBPIXELS * SUBPIXELS) as f64;
    (total as f64 / per_pixel, crossing as f64 / (per_pixel * width as f64 * height as f64))
}

/// The passes of one case: (group, kernel, parameter states, marches per sample); `loss`
/// looks up no voxel.
const PASSES: [(&str, &str, u64, u64); 6] = [
    ("gradient", "trace_primal", 1, 1),
    ("gradient", "loss", 0, 0),
    ("gradient", "trace_adjoint", 1, 2),
    ("finite_difference", "trace_fd_primal", 2, 1),
    ("finite_difference", "loss", 0, 0),
    ("finite_difference", "trace_fd_adjoint", 2, 2),
];

fn measure_case(device: &crate::device::Device, grid: u32, film: u32, iterations: u32, warm_up: Duration) -> Result<MediaCase> {
    let ctx = device.ctx();
    let scene = synthetic_scene(grid, film)?;
    let mut st = RunSettings::of_scene(&scene);
    // One sample per pixel everywhere, and a target of one sample (its content does not
    // change the work).
    (st.spp, st.primal_spp, st.fd_spp, st.target_spp, st.fd_stride) = (1, 1, 1, 1, 1);
    let engine = Engine::gradient_only(device, &scene, &st)?;
    let gs = engine.scene();
    let theta_prev = gs.theta.duplicate("theta prev")?;
    let fd = engine.fd_sample(&theta_prev, false, None)?;
    // θ_prev as after a step (2 % below θ), not θ itself: with equal states the fused
    // adjoint's derivatives cancel and it scatters nothing, which no later iteration does.
    let prev: Vec<f32> = gs.read_theta()?.iter().map(|v| 0.98 * v).collect();
    theta_prev.write(&prev)?;

    let mut profs = [Profiler::new(ctx, Profiler::SCOPES)?, Profiler::new(ctx, Profiler::SCOPES)?];
    let mut cmds = [CommandBuffer::new(ctx, "media bench gradient")?, CommandBuffer::new(ctx, "media bench finite difference")?];
    {
        let [gp, fp] = &mut profs;
        cmds[0].record(|rec| {
            gp.reset(rec);
            rec.with_profiler(gp, |rec| engine.record_gradient(rec))
        })?;
        cmds[1].record(|rec| {
            fp.reset(rec);
            rec.with_profiler(fp, |rec| fd.record(rec, gs, &engine.ops, &engine.fd_grad))
        })?;
    }
    // The first round compiles the pipelines (lavapipe); more follow for `warm_up`.
    let round = |cmds: &mut [CommandBuffer; 2]| -> Result<()> {
        for c in cmds.iter_mut() {
            c.submit_and_wait()?;
        }
        Ok(())
    };
    round(&mut cmds)?;
    let start = Instant::now();
    while start.elapsed() < warm_up {
        round(&mut cmds)?;
    }
    // Each group in its own submission: at 128³ voxels on a 256² film a CPU device takes
    // seconds per group.
    let mut samples = [Samples::default(), Samples::default()];
    for i in 0..iterations {
        gs.set_frame(i + 1)?;
        for ((c, p), s) in cmds.iter_mut().zip(&profs).zip(&mut samples) {
            c.submit_and_wait()?;
            s.add(&p.results()?);
        }
    }

    let step = scene.media[0].world_step();
    let (film_steps, crossing_fraction) = march_steps(&scene.sensors[0], gs.width, gs.height, step);
    let rays = gs.width as f64 * gs.height as f64;
    let group = |name: &str| &samples[usize::from(name != "gradient")];
    let passes: Vec<MediaPass> = PASSES
        .iter()
        .map(|&(g, name, states, marches)| {
            let ms = group(g).median(name);
            let spp = match g {
                "gradient" if name == "trace_primal" => st.primal_spp,
                "gradient" => st.spp,
                _ => st.fd_spp,
            };
            let lookups = (states > 0).then(|| (film_steps * spp as f64).round() as u64 * TAPS * GRIDS * states * marches);
            MediaPass {
                group: g.into(),
                name: name.into(),
                spp: (states > 0).then_some(spp),
                median_ms: ms,
                voxel_lookups: lookups,
                lookups_per_s: lookups.map(|l| l as f64 / (ms * 1e-3).max(1e-12)),
            }
        })
        .collect();
    let (primal, adjoint) = (samples[0].median("trace_primal"), samples[0].median("trace_adjoint"));
    Ok(MediaCase {
        grid,
        width: gs.width,
        height: gs.height,
        parameters: gs.layout.len,
        step,
        crossing_fraction,
        steps_per_ray: film_steps / rays,
        steps_per_crossing_ray: film_steps / (rays * crossing_fraction).max(1e-12),
        passes,
        adjoint_over_primal: adjoint / primal.max(1e-12),
        fd_over_gradient: samples[1].total() / samples[0].total().max(1e-12),
    })
}

impl MediaBench {
    /// The results as fixed-width tables.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "media bench on {}: a {:?}-{:?} box of emitting and absorbing medium (smooth random density and emission grids, both optimised), \
             one perspective camera, constant environment, no meshes; median of {} iterations, LP_NUM_THREADS={}",
            self.device,
            self.box_min,
            self.box_max,
            self.iterations,
            self.lp_num_threads.as_deref().unwrap_or("unset")
        );
        let _ = writeln!(
            s,
            "voxel lookups = march steps x {TAPS} taps x {GRIDS} grids (density, emission) x parameter states x marches per sample; \
             steps from each camera ray's clip length on the host ({SUBPIXELS}x{SUBPIXELS} rays per pixel)"
        );
        let _ = writeln!(s, "{:<6} {:>9} {:>10} {:<36} {:>4} {:>11} {:>12}", "grid", "film", "steps/ray", "group / pass", "spp", "median ms", "Glookups/s");
        for c in &self.cases {
            for p in &c.passes {
                let rate = p.lookups_per_s.map(|r| format!("{:.3}", r * 1e-9)).unwrap_or_default();
                let spp = p.spp.map(|v| v.to_string()).unwrap_or_default();
                let _ = writeln!(
                    s,
                    "{:<6} {:>9} {:>10.1} {:<36} {:>4} {:>11.3} {:>12}",
                    format!("{}^3", c.grid),
                    format!("{}x{}", c.width, c.height),
                    c.steps_per_ray,
                    format!("{} / {}", p.group, p.name),
                    spp,
                    p.median_ms,
                    rate
                );
            }
            let _ = writeln!(
                s,
                "{:<6} {:>9} {:>10} rays crossing the box {:.1} %, {:.1} steps each (step {:.5}); trace_adjoint / trace_primal = {:.2}, finite_difference / gradient = {:.2}",
                "",
                "",
                "",
                100.0 * c.crossing_fraction,
                c.steps_per_crossing_ray,
                c.step,
                c.adjoint_over_primal,
                c.fd_over_gradient
            );
        }
        s.push_str(&self.optimisers.table());
        s
    }
}
