//! Importance sampling of a lat-long environment map for next-event estimation.
//!
//! The map is divided into its texel cells: cell (r, c) covers columns u ∈ [c/W, (c+1)/W)
//! (azimuth) and rows θ ∈ [πr/H, π(r+1)/H) (polar angle from +y, row 0 up), as
//! `environment_uv` in glsl/lib/scene_access.glsl maps directions. A cell is picked by a
//! piecewise-constant 2D distribution (marginal over rows, then conditional within the
//! row), and a direction inside it uniformly in solid angle (φ uniform, cos θ uniform
//! between the row's bounds), so the density in solid angle is constant over a cell:
//! `pmf(r, c) / Ω(r, c)`, with no 1/sin θ singularity at the poles.
//!
//! Cell weights: the mean over the cell of the *bilinearly filtered* luminance (the lookup
//! blends each texel with its neighbours, so a bright texel lights a 3 × 3 block of cells
//! with weights 1/8, 3/4, 1/8 per axis; wrapping as the lookup wraps) times the cell's
//! solid angle, mixed with a share [`UNIFORM_SHARE`] of the uniform distribution over the
//! sphere. The uniform share makes the density positive in every direction, so the
//! estimator stays unbiased wherever the looked-up radiance differs from what the
//! distribution was built from: between texel centres (filtering) and, for an optimised
//! environment, at every iteration after the first. The distribution is built once, from
//! the map's initial value (θ's start value for an optimised map), and is a constant with
//! respect to θ, as the kernels' other sampling decisions are.
//!
//! GPU layout (binding `EnvDistribution`, floats): the inclusive cdf over rows (H), then
//! per row the inclusive cdf over its columns conditional on the row (H × W), then the
//! density in solid angle of each cell (H × W). Rows are stored top first.

use std::f64::consts::PI;

/// Share of the uniform-over-the-sphere distribution in the mix.
pub const UNIFORM_SHARE: f64 = 0.1;

/// Kernel of the mean of the bilinear lookup over one cell, per axis: the cell itself and
/// its two neighbours.
const FILTER: [f64; 3] = [0.125, 0.75, 0.125];

/// The piecewise-constant distribution over the cells of a `width` × `height` lat-long map.
#[derive(Clone, Debug)]
pub struct EnvDistribution {
    pub width: u32,
    pub height: u32,
    /// Inclusive cdf over rows (`height`), the last exactly 1.
    pub row_cdf: Vec<f32>,
    /// Per row, the inclusive cdf over its columns given the row (`height × width`).
    pub col_cdf: Vec<f32>,
    /// Density in solid angle of each cell (`height × width`).
    pub density: Vec<f32>,
    /// Probability of each cell (`height × width`), in f64.
    pub pmf: Vec<f64>,
}

/// Lat-long texture coordinates of a direction, as glsl/lib/scene_access.glsl
/// `environment_uv`: u = azimuth around +y (atan2(x, −z)), v = 1 − θ/π (top row up).
pub fn environment_uv(dir: [f64; 3]) -> [f64; 2] {
    let u = dir[0].atan2(-dir[2]) * (0.5 / PI) + 0.5;
    let v = 1.0 - dir[1].clamp(-1.0, 1.0).acos() / PI;
    [u, v]
}

/// 1 − cos(θ) at θ = π·k/h, without cancellation near θ = 0.
fn one_minus_cos(k: f64, h: f64) -> f64 {
    let s = (0.5 * PI * k / h).sin();
    2.0 * s * s
}

impl EnvDistribution {
    /// The distribution of a `width` × `height` map of RGB texels (`3·width·height`
    /// floats, row-major, top row first).
    pub fn new(texels: &[f32], width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        assert!(w > 0 && h > 0 && texels.len() >= 3 * w * h, "environment map {width}×{height} with {} floats", texels.len());
        let lum: Vec<f64> = (0..w * h)
            .map(|i| {
                let t = &texels[3 * i..3 * i + 3];
                crate::bsdf::LUMINANCE.dot(glam::DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)).max(0.0)
            })
            .collect();
        let mut weight = vec![0.0f64; w * h];
        let mut omega = vec![0.0f64; w * h];
        for r in 0..h {
            let row_omega = Self::cell_solid_angle(width, height, r as u32);
            for c in 0..w {
                let mut mean = 0.0;
                for (dr, kr) in FILTER.iter().enumerate() {
                    let rr = (r + h + dr - 1) % h;
                    for (dc, kc) in FILTER.iter().enumerate() {
                        let cc = (c + w + dc - 1) % w;
                        mean += kr * kc * lum[rr * w + cc];
                    }
                }
                weight[r * w + c] = mean * row_omega;
                omega[r * w + c] = row_omega;
            }
        }
        let total: f64 = weight.iter().sum();
        let sphere = 4.0 * PI;
        let pmf: Vec<f64> = weight
            .iter()
            .zip(&omega)
            .map(|(wt, om)| if total > 0.0 && total.is_finite() { (1.0 - UNIFORM_SHARE) * wt / total + UNIFORM_SHARE * om / sphere } else { om / sphere })
            .collect();
        let norm: f64 = pmf.iter().sum();
        let pmf: Vec<f64> = pmf.iter().map(|p| p / norm).collect();

        let mut row_cdf = Vec::with_capacity(h);
        let mut col_cdf = Vec::with_capacity(w * h);
        let mut acc = 0.0;
        for r in 0..h {
            let row = &pmf[r * w..(r + 1) * w];
            let row_sum: f64 = row.iter().sum();
            acc += row_sum;
            row_cdf.push(if r + 1 == h { 1.0 } else { acc as f32 });
            let mut cacc = 0.0;
            for (c, p) in row.iter().enumerate() {
                cacc += p;
                col_cdf.push(if c + 1 == w { 1.0 } else { (cacc / row_sum) as f32 });
            }
        }
        let density = pmf.iter().zip(&omega).map(|(p, om)| (p / om) as f32).collect();
        Self { width, height, row_cdf, col_cdf, density, pmf }
    }

    /// Solid angle of a cell of row `row`: (2π/W)·(cos θ₀ − cos θ₁).
    pub fn cell_solid_angle(width: u32, height: u32, row: u32) -> f64 {
        let h = height as f64;
        2.0 * PI / width as f64 * (one_minus_cos(row as f64 + 1.0, h) - one_minus_cos(row as f64, h))
    }

    /// The floats of the `EnvDistribution` buffer.
    pub fn gpu_data(&self) -> Vec<f32> {
        let mut v = self.row_cdf.clone();
        v.extend_from_slice(&self.col_cdf);
        v.extend_from_slice(&self.density);
        v
    }

    /// The cell (row, column) that contains direction `dir`, as the kernel finds it.
    pub fn cell(&self, dir: [f64; 3]) -> (usize, usize) {
        let [u, v] = environment_uv(dir);
        let c = ((u.max(0.0) * self.width as f64) as usize).min(self.width as usize - 1);
        let r = (((1.0 - v).max(0.0) * self.height as f64) as usize).min(self.height as usize - 1);
        (r, c)
    }

    /// Density in solid angle of direction `dir`.
    pub fn pdf(&self, dir: [f64; 3]) -> f64 {
        let (r, c) = self.cell(dir);
        self.density[r * self.width as usize + c] as f64
    }

    /// A direction from two uniform numbers, and its density: the f64 mirror of
    /// `environment_sample` (glsl/lib/scene_access.glsl). Each number picks a cell index
    /// and is then rescaled to [0, 1) to place the direction inside the cell.
    pub fn sample(&self, u: [f64; 2]) -> ([f64; 3], f64) {
        let (w, h) = (self.width as usize, self.height as usize);
        let pick = |cdf: &[f32], x: f64| -> (usize, f64) {
            let i = cdf.iter().position(|&c| c as f64 > x).unwrap_or(cdf.len() - 1);
            let lo = if i == 0 { 0.0 } else { cdf[i - 1] as f64 };
            let hi = cdf[i] as f64;
            (i, ((x - lo) / (hi - lo).max(1e-30)).clamp(0.0, 1.0))
        };
        let (r, ur) = pick(&self.row_cdf, u[0]);
        let (c, uc) = pick(&self.col_cdf[r * w..(r + 1) * w], u[1]);
        let hf = h as f64;
        let (h0, h1) = (one_minus_cos(r as f64, hf), one_minus_cos(r as f64 + 1.0, hf));
        let one_minus = h0 + (h1 - h0) * ur;
        let ct = 1.0 - one_minus;
        let st = (one_minus * (2.0 - one_minus)).max(0.0).sqrt();
        let phi = 2.0 * PI * ((c as f64 + uc) / w as f64 - 0.5);
        ([st * phi.sin(), ct, -st * phi.cos()], self.density[r * w + c] as f64)
    }
}
