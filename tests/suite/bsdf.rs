//! The BSDFs of glsl/lib/bsdf.glsl against their f64 mirror (src/bsdf.rs), and the
//! mirror against the properties the model must have: samples distributed as the pdf says
//! (chi-square), no energy gain (white furnace), derivatives equal to finite differences,
//! reciprocity. Every threshold is derived in a comment next to it.

use crate::common;

use bytemuck::{Pod, Zeroable};
use common::{check_layout, with_gpu};
use glam::DVec3;
use std::f64::consts::PI;
use vkinverse::bsdf::{self, MaterialF64, ShadingFrame, ALPHA_MIN};
use vkinverse::gpu::{Buffer, CommandBuffer, ComputePipeline, MemoryKind};
use vkinverse::shared::{
    Material, COATING_NONLINEAR, COATING_UNLAYERED, MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_DIELECTRIC, MATERIAL_DIFFUSE, MATERIAL_PLASTIC,
    MATERIAL_PLASTIC_BECKMANN, MATERIAL_PRINCIPLED, MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN, MATERIAL_THIN_DIELECTRIC,
};
use vkinverse::stats::ln_gamma;

// ---------------------------------------------------------------------------------------
// Plastic coatings: their tables, concatenated as the test kernel reads them (`Tables`)
// ---------------------------------------------------------------------------------------

/// Coatings of both distributions, rough and nearly smooth, from outside and of a dense
/// index: (kind, roughness, ior).
const COATINGS: [(u32, f32, f32); 4] =
    [(MATERIAL_PLASTIC, 0.3, 1.5), (MATERIAL_PLASTIC_BECKMANN, 0.5, 1.49), (MATERIAL_PLASTIC, 0.05, 1.33), (MATERIAL_PLASTIC_BECKMANN, 0.2, 2.0)];

/// The tables of [`COATINGS`], one after the other, and each one's internal reflectance.
fn coating_tables() -> &'static (Vec<f32>, Vec<f32>) {
    static TABLES: std::sync::OnceLock<(Vec<f32>, Vec<f32>)> = std::sync::OnceLock::new();
    TABLES.get_or_init(|| {
        let (mut tables, mut internal) = (Vec::new(), Vec::new());
        for (kind, roughness, ior) in COATINGS {
            let (t, r) = bsdf::coating(kind == MATERIAL_PLASTIC_BECKMANN, f64::from(roughness), f64::from(ior));
            tables.extend(t.iter().map(|x| *x as f32));
            internal.push(r as f32);
        }
        (tables, internal)
    })
}

/// A plastic's coating flags from a draw `u` in [0, 1): layered, layered and nonlinear,
/// or unlayered, a third each.
fn coating_flags(u: f64) -> u32 {
    [0, COATING_NONLINEAR, COATING_UNLAYERED][((u * 3.0) as usize).min(2)]
}

/// Plastic `i` of [`COATINGS`] with diffuse reflectance `base` and coating `flags` (an
/// unlayered one has no table and no internal reflectance).
fn plastic(i: usize, base: [f32; 3], flags: u32) -> Material {
    let (kind, roughness, ior) = COATINGS[i];
    let layered = flags & COATING_UNLAYERED == 0;
    Material {
        base_color: base,
        roughness,
        kind,
        ior,
        table: if layered { (i * bsdf::TABLE) as u32 } else { 0 },
        internal: if layered { coating_tables().1[i] } else { 0.0 },
        coating: flags,
        specular: [1.0; 3],
        ..Default::default()
    }
}

/// The mirror of `m`, with its table if it is a plastic.
fn mirror(m: Material) -> MaterialF64 {
    MaterialF64::with_tables(m, &coating_tables().0)
}

// ---------------------------------------------------------------------------------------
// Mirrors of the test kernel's structs (glsl/bsdf_test.comp), checked by reflection below.
// ---------------------------------------------------------------------------------------

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct BsdfCase {
    n: [f32; 3],
    wo: [f32; 3],
    wi: [f32; 3],
    u: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct BsdfResult {
    value: [f32; 3],
    pdf: f32,
    sample_wi: [f32; 3],
    sample_weight: [f32; 3],
    sample_pdf: f32,
    sample_ok: u32,
    d_base_color: [f32; 3],
    d_roughness: [f32; 3],
    d_metallic: [f32; 3],
}

use vkinverse::kernels::BsdfSamplePush as SamplePush;

#[test]
fn struct_layouts_match_reflection() {
    use std::mem::{offset_of, size_of};
    let material = [
        ("base_color", offset_of!(Material, base_color)),
        ("roughness", offset_of!(Material, roughness)),
        ("metallic", offset_of!(Material, metallic)),
        ("kind", offset_of!(Material, kind)),
        ("ior", offset_of!(Material, ior)),
        ("eta", offset_of!(Material, eta)),
        ("k", offset_of!(Material, k)),
        ("table", offset_of!(Material, table)),
        ("internal", offset_of!(Material, internal)),
        ("coating", offset_of!(Material, coating)),
        ("specular", offset_of!(Material, specular)),
        ("pad", offset_of!(Material, pad)),
    ];
    check_layout("bsdf_test", "Material", &material, size_of::<Material>());
    // The sampling variant passes Material in its push constants.
    check_layout("bsdf_sample_test", "Material", &material, size_of::<Material>());
    check_layout(
        "bsdf_test",
        "BsdfCase",
        &[("n", offset_of!(BsdfCase, n)), ("wo", offset_of!(BsdfCase, wo)), ("wi", offset_of!(BsdfCase, wi)), ("u", offset_of!(BsdfCase, u))],
        size_of::<BsdfCase>(),
    );
    check_layout(
        "bsdf_test",
        "BsdfResult",
        &[
            ("value", offset_of!(BsdfResult, value)),
            ("pdf", offset_of!(BsdfResult, pdf)),
            ("sample_wi", offset_of!(BsdfResult, sample_wi)),
            ("sample_weight", offset_of!(BsdfResult, sample_weight)),
            ("sample_pdf", offset_of!(BsdfResult, sample_pdf)),
            ("sample_ok", offset_of!(BsdfResult, sample_ok)),
            ("d_base_color", offset_of!(BsdfResult, d_base_color)),
            ("d_roughness", offset_of!(BsdfResult, d_roughness)),
            ("d_metallic", offset_of!(BsdfResult, d_metallic)),
        ],
        size_of::<BsdfResult>(),
    );
    let spirv = vkinverse::gpu::shaders::get("bsdf_sample_test").unwrap();
    let r = vkinverse::gpu::reflect::Reflection::new("bsdf_sample_test", spirv).unwrap();
    assert_eq!(r.push_constant_size as usize, size_of::<SamplePush>());
}

// ---------------------------------------------------------------------------------------
// Helpers: random numbers, directions, statistics
// ---------------------------------------------------------------------------------------

/// SplitMix64 (Steele et al. 2014): deterministic, and good enough for test inputs and
/// the CPU Monte Carlo estimates.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e3779b97f4a7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }

    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[(self.next_u64() % items.len() as u64) as usize]
    }

    fn unit_vector(&mut self) -> DVec3 {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, 2.0 * PI);
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// The direction at cos theta = `cos` and azimuth `phi` about `n`.
fn direction(n: DVec3, cos: f64, phi: f64) -> DVec3 {
    let f = ShadingFrame::new(n);
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    f.to_world(DVec3::new(sin * phi.cos(), sin * phi.sin(), cos))
}

fn v3(v: [f32; 3]) -> DVec3 {
    DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
}

fn f3(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// Regularised upper incomplete gamma Q(a, x): series below a + 1, Lentz continued
/// fraction above (Numerical Recipes, 3rd ed., section 6.2).
fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let ln_prefix = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut ap, mut del) = (a, 1.0 / a);
        let mut sum = del;
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        1.0 - sum * ln_prefix.exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        ln_prefix.exp() * h
    }
}

/// Upper tail of the standard normal distribution, P(Z > z) = Q(1/2, z^2/2) / 2 for z >= 0.
fn normal_upper_tail(z: f64) -> f64 {
    0.5 * gamma_q(0.5, 0.5 * z * z)
}

/// The z with P(Z > z) = p (bisection; p in (0, 1/2)).
fn normal_quantile_upper(p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 40.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if normal_upper_tail(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Per-test significance for a family of `m` tests at family-wise level `alpha`
/// (Šidák correction).
fn sidak(alpha: f64, m: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / m as f64)
}

#[test]
fn statistics_helpers_are_right() {
    // Known values: Q(1, x) = e^-x, P(Z > 1.959963985) = 0.025, and Q(a, x) from mpmath's
    // gammainc(a, x, regularized=True) on both sides of the series/fraction switch.
    for x in [0.1, 1.0, 3.0, 30.0] {
        assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-13 * (-x).exp().max(1e-300) + 1e-15, "Q(1, {x})");
    }
    assert!((gamma_q(5.0, 2.0) - 0.947_346_982_656_289).abs() < 1e-12);
    assert!((gamma_q(50.0, 60.0) - 0.084_406_681_093_691_8).abs() < 1e-12);
    assert!((gamma_q(200.0, 150.0) - 0.999_942_903_114_258).abs() < 1e-12);
    assert!((normal_quantile_upper(0.025) - 1.959_963_985).abs() < 1e-8);
    assert!((ln_gamma(10.0) - 362_880f64.ln()).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------
// (a) + (d, GPU part): the GLSL functions agree with the f64 mirror
// ---------------------------------------------------------------------------------------

/// Everything the test kernel returns for one case, from the mirror: 21 numbers in the
/// order of `BsdfResult`.
fn mirror_outputs(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3, u: DVec3) -> [f64; 21] {
    // A dielectric's kernel case reports its delta lobes' functions in the same slots.
    let (value, pdf, s, g) = if m.dielectric() {
        let g = bsdf::EvalGrad { d_base_color: bsdf::dielectric_mass_grad(m, n, wo, wi), ..Default::default() };
        (bsdf::dielectric_mass(m, n, wo, wi), bsdf::dielectric_prob(m, n, wo, wi), bsdf::dielectric_sample(m, n, wo, u.x), g)
    } else {
        (bsdf::eval(m, n, wo, wi), bsdf::pdf(m, n, wo, wi), bsdf::sample(m, n, wo, u), bsdf::eval_grad(m, n, wo, wi))
    };
    let (swi, sweight, spdf, ok) = match s {
        Some(s) => (s.wi, s.weight, s.pdf, 1.0),
        None => (DVec3::ZERO, DVec3::ZERO, 0.0, 0.0),
    };
    let mut out = [0.0; 21];
    let parts: [&[f64]; 9] = [
        &value.to_array(),
        &[pdf],
        &swi.to_array(),
        &sweight.to_array(),
        &[spdf],
        &[ok],
        &g.d_base_color.to_array(),
        &g.d_roughness.to_array(),
        &g.d_metallic.to_array(),
    ];
    let mut k = 0;
    for p in parts {
        out[k..k + p.len()].copy_from_slice(p);
        k += p.len();
    }
    out
}

fn result_outputs(r: &BsdfResult) -> [f64; 21] {
    let mut out = [0.0; 21];
    let f: Vec<f64> =
        [&r.value[..], &[r.pdf], &r.sample_wi, &r.sample_weight, &[r.sample_pdf], &[r.sample_ok as f32], &r.d_base_color, &r.d_roughness, &r.d_metallic]
            .concat()
            .into_iter()
            .map(|x| x as f64)
            .collect();
    out.copy_from_slice(&f);
    out
}

const OUTPUT_NAMES: [&str; 21] = [
    "value.r",
    "value.g",
    "value.b",
    "pdf",
    "sample_wi.x",
    "sample_wi.y",
    "sample_wi.z",
    "sample_weight.r",
    "sample_weight.g",
    "sample_weight.b",
    "sample_pdf",
    "sample_ok",
    "d_base_color.r",
    "d_base_color.g",
    "d_base_color.b",
    "d_roughness.r",
    "d_roughness.g",
    "d_roughness.b",
    "d_metallic.r",
    "d_metallic.g",
    "d_metallic.b",
];

/// Random cases that cover what the GPU must get right: both kinds, roughness 0 (the
/// alpha clamp), 1 and in between, metallic 0/1/between, normals at the poles and on the
/// equator (the two branches of the frame), grazing and below-surface directions, wi near
/// the mirror direction (the specular peak) and lobe-selection numbers at the ends.
fn random_cases(count: usize, seed: u64) -> Vec<(Material, BsdfCase)> {
    let mut rng = Rng(seed);
    (0..count)
        .map(|i| {
            let kind = match i % 7 {
                3 if i % 2 == 0 => MATERIAL_THIN_DIELECTRIC,
                3 => MATERIAL_DIELECTRIC,
                5 if i % 4 == 0 => MATERIAL_ROUGH_DIELECTRIC,
                5 if i % 4 == 2 => MATERIAL_ROUGH_DIELECTRIC_BECKMANN,
                5 if i % 4 == 1 => MATERIAL_CONDUCTOR,
                5 => MATERIAL_CONDUCTOR_BECKMANN,
                6 if i % 3 == 0 => MATERIAL_PLASTIC,
                _ if i % 5 == 0 => MATERIAL_DIFFUSE,
                _ => MATERIAL_PRINCIPLED,
            };
            let mut base = [0f32; 3];
            for b in &mut base {
                let x = rng.f64();
                *b = rng.pick(&[0.0, 1.0, x, x, x]) as f32;
            }
            let (r, m) = (rng.f64(), rng.f64());
            let material = Material {
                base_color: base,
                roughness: rng.pick(&[0.0, 1.0, 0.05, r, r, r]) as f32,
                metallic: rng.pick(&[0.0, 1.0, m, m]) as f32,
                kind,
                // Index-matched (not for rough glass, whose refraction is then a delta and
                // which the loader refuses), glass from outside and inside, water, and any
                // in between.
                ior: if kind == MATERIAL_ROUGH_DIELECTRIC || kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN {
                    rng.pick(&[1.5, 1.0 / 1.5, 1.33, 0.5 + 2.0 * r, 0.5 + 2.0 * r])
                } else {
                    rng.pick(&[1.0, 1.5, 1.0 / 1.5, 1.33, 0.5 + 2.0 * r])
                } as f32,
                ..Default::default()
            };
            let mut material = material;
            if kind == MATERIAL_CONDUCTOR || kind == MATERIAL_CONDUCTOR_BECKMANN {
                // Gold, aluminium, a perfect mirror (eta 0, k 1), a dielectric's index (k 0)
                // and any in between.
                let pick = |rng: &mut Rng, hi: f64| [rng.range(0.0, hi), rng.range(0.0, hi), rng.range(0.0, hi)].map(|x| x as f32);
                [material.eta, material.k] = match rng.next_u64() % 6 {
                    0 => vkinverse::scene::metal("Au").unwrap(),
                    1 => vkinverse::scene::metal("Al").unwrap(),
                    2 => vkinverse::scene::metal("none").unwrap(),
                    3 => [[1.5; 3], [0.0; 3]],
                    _ => [pick(&mut rng, 4.0), pick(&mut rng, 8.0)],
                };
            }
            if kind == MATERIAL_PLASTIC {
                // One of the coatings, linear or not, every other one with a specular tint.
                material = plastic(rng.next_u64() as usize % COATINGS.len(), base, coating_flags(rng.f64()));
                if i % 2 == 0 {
                    material.specular = [0.3, 0.9, 0.0];
                }
            }
            let n = match i % 16 {
                0 => DVec3::Z,
                1 => -DVec3::Z,
                2 => DVec3::new(0.6, -0.8, 0.0),
                _ => rng.unit_vector(),
            };
            let cosine = |rng: &mut Rng| match rng.next_u64() % 8 {
                0 => 10f64.powf(rng.range(-3.0, -1.0)),
                1 => -rng.f64(),
                2 => 1.0,
                _ => rng.f64(),
            };
            let wo = direction(n, cosine(&mut rng), rng.range(0.0, 2.0 * PI));
            let wi = if rng.f64() < 0.25 {
                // Near the mirror direction of wo, within 10^-3 to 10^-0.5 radians.
                let mirror = 2.0 * wo.dot(n) * n - wo;
                let tilt = 10f64.powf(rng.range(-3.0, -0.5));
                (mirror + tilt * rng.unit_vector()).normalize()
            } else if (kind == MATERIAL_ROUGH_DIELECTRIC || kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN) && rng.f64() < 0.5 {
                // Near the refracted direction (the transmitted lobe's peak), or anywhere
                // below the surface.
                let m = mirror(material);
                match bsdf::dielectric_sample(&MaterialF64 { kind: MATERIAL_DIELECTRIC, ..m }, n, wo, 1.0 - 1e-9) {
                    Some(t) if t.wi.dot(n) < 0.0 && rng.f64() < 0.6 => (t.wi + 10f64.powf(rng.range(-3.0, -0.5)) * rng.unit_vector()).normalize(),
                    _ => direction(n, -rng.f64(), rng.range(0.0, 2.0 * PI)),
                }
            } else {
                direction(n, cosine(&mut rng), rng.range(0.0, 2.0 * PI))
            };
            let ux = rng.f64();
            // (Not u.x = 0 for a dielectric: index-matched, its reflectance is 0 in exact
            // arithmetic but a rounding's width above or below it, so the lobe at u.x = 0 is
            // a tie the two precisions break differently.)
            let lowest = if kind == MATERIAL_DIELECTRIC || kind == MATERIAL_THIN_DIELECTRIC { 1e-3 } else { 0.0 };
            let u = [rng.pick(&[lowest, 0.999_999, ux, ux]), rng.f64(), rng.f64()];
            let case = BsdfCase { n: f3(n), wo: f3(wo), wi: f3(wi), u: u.map(|x| x as f32) };
            (material, case)
        })
        .collect()
}

fn run_bsdf_test(ctx: &std::sync::Arc<vkinverse::gpu::Context>, cases: &[(Material, BsdfCase)]) -> Vec<BsdfResult> {
    let pipe = ComputePipeline::new(ctx, "bsdf_test", &[]).unwrap();
    let materials: Vec<Material> = cases.iter().map(|c| c.0).collect();
    let inputs: Vec<BsdfCase> = cases.iter().map(|c| c.1).collect();
    let mbuf = Buffer::from_slice(ctx, "materials", &materials, MemoryKind::Upload).unwrap();
    let cbuf = Buffer::from_slice(ctx, "cases", &inputs, MemoryKind::Upload).unwrap();
    let rbuf = Buffer::zeroed::<BsdfResult>(ctx, "results", cases.len(), MemoryKind::Readback).unwrap();
    let tbuf = Buffer::from_slice(ctx, "tables", &coating_tables().0, MemoryKind::Upload).unwrap();
    let group = pipe.bind(&[("Materials", &mbuf), ("Cases", &cbuf), ("Results", &rbuf), ("Tables", &tbuf)]).unwrap();
    let mut cmd = CommandBuffer::new(ctx, "bsdf_test").unwrap();
    let push = vkinverse::kernels::CountPush::new(cases.len() as u64);
    cmd.record(|rec| rec.dispatch_linear(&pipe, &group, &push, cases.len() as u64)).unwrap();
    cmd.submit_and_wait().unwrap();
    rbuf.read().unwrap()
}

#[test]
fn gpu_matches_cpu_mirror() {
    // Not a multiple of the workgroup size (64), so the kernel's bounds check is exercised.
    let cases = random_cases(4099, 1);
    let results = with_gpu(|ctx| run_bsdf_test(ctx, &cases));

    // Tolerance. The kernel computes in float32 and the mirror in f64 from the same
    // float32 inputs. Float32 evaluation of these formulas is backward stable: the GPU's
    // result is the exact function at inputs perturbed by a few ulps, plus a relative
    // error of a few ulps in the result. The second part is bounded by 1e-4 (about 1700
    // float32 ulps, ample for the ~50 operations in a row). The first part depends on the
    // conditioning of each case, which is extreme near the GGX peak at alpha = 1e-3 (D
    // changes by 4 (dt/t) when h's tangential part t changes) or at a lobe-selection or
    // below-surface boundary (the output jumps). It is measured: the mirror is evaluated
    // at inputs perturbed by up to 16 ulps (2^-20 relative, more than the GPU's rounding
    // of the frame, dot products and normalisations), and 4x the largest change over 8
    // random perturbations is allowed on top.
    const REL: f64 = 1e-4;
    const PERTURB: f64 = 1.0 / (1u64 << 20) as f64;
    let mut rng = Rng(99);
    let mut ill_conditioned = 0;
    let mut max_err: f64 = 0.0;
    let mut max_ratio: f64 = 0.0;
    let mut failures = Vec::new();
    for (i, ((mat, case), r)) in cases.iter().zip(&results).enumerate() {
        let m = mirror(*mat);
        let (n, wo, wi, u) = (v3(case.n), v3(case.wo), v3(case.wi), v3(case.u));
        let mut cpu = mirror_outputs(&m, n, wo, wi, u);
        let mut gpu = result_outputs(r);
        // With wo along n the VNDF basis is arbitrary (Heitz 2018, section 4.1), so within
        // rounding of the pole the GPU and the mirror may rotate the sample differently
        // about n: compare its cosine only, which that rotation leaves alone.
        let wo_local = ShadingFrame::new(n).to_local(wo);
        if wo_local.x.hypot(wo_local.y) < 1e-5 {
            for out in [&mut cpu, &mut gpu] {
                let cos = DVec3::new(out[4], out[5], out[6]).dot(n);
                out[4..7].copy_from_slice(&[cos, 0.0, 0.0]);
            }
        }
        let mut sens = [0.0f64; 21];
        for _ in 0..8 {
            let p = |x: f64, rng: &mut Rng| x * (1.0 + PERTURB * rng.range(-1.0, 1.0));
            let pv = |v: DVec3, rng: &mut Rng| DVec3::new(p(v.x, rng), p(v.y, rng), p(v.z, rng));
            let mp = MaterialF64 {
                base_color: pv(m.base_color, &mut rng),
                roughness: p(m.roughness, &mut rng),
                metallic: p(m.metallic, &mut rng),
                kind: m.kind,
                ior: p(m.ior, &mut rng),
                eta: pv(m.eta, &mut rng),
                k: pv(m.k, &mut rng),
                internal: p(m.internal, &mut rng),
                ..m
            };
            let (pn, pwo) = (pv(n, &mut rng), pv(wo, &mut rng));
            let mut out = mirror_outputs(&mp, pn, pwo, pv(wi, &mut rng), pv(u, &mut rng));
            if wo_local.x.hypot(wo_local.y) < 1e-5 {
                let cos = DVec3::new(out[4], out[5], out[6]).dot(pn);
                out[4..7].copy_from_slice(&[cos, 0.0, 0.0]);
            }
            for k in 0..21 {
                sens[k] = sens[k].max((out[k] - cpu[k]).abs());
            }
        }
        if (0..21).any(|k| sens[k] > 1e-3 * cpu[k].abs().max(1e-3)) {
            ill_conditioned += 1;
        }
        for k in 0..21 {
            let err = (gpu[k] - cpu[k]).abs();
            // Beckmann's exp(-tan^2 / alpha^2) leaves float32's range far from its peak:
            // below 1e-30 (of the result's scale) the kernel's 0 is its rounding.
            let tol = REL * cpu[k].abs() + 4.0 * sens[k] + 1e-30;
            if tol > 0.0 {
                max_ratio = max_ratio.max(err / tol);
            }
            if err.is_nan() || err > tol {
                failures.push(format!("case {i} {}: gpu {} cpu {} (tol {tol:e}); {mat:?} {case:?}", OUTPUT_NAMES[k], gpu[k], cpu[k]));
            }
            if sens[k] <= 1e-6 * cpu[k].abs() && cpu[k] != 0.0 {
                max_err = max_err.max(err / cpu[k].abs());
            }
        }
    }
    println!(
        "{ill_conditioned} of {} cases ill-conditioned; largest relative error where well conditioned: {max_err:.2e}; \
         largest error / tolerance: {max_ratio:.3}",
        cases.len()
    );
    assert!(failures.is_empty(), "{} mismatches:\n{}", failures.len(), failures[..failures.len().min(20)].join("\n"));
    // The perturbation allowance must not make the comparison vacuous: most cases are well
    // conditioned (the generator puts at most ~1/4 of them near a peak or a boundary).
    assert!(ill_conditioned * 4 < cases.len(), "{ill_conditioned} ill-conditioned cases");
}

// ---------------------------------------------------------------------------------------
// (b) chi-square goodness of fit of the GPU samples against bsdf_pdf
// ---------------------------------------------------------------------------------------

/// Adaptive Simpson quadrature of `f` over [a, b] to absolute error `eps` (the usual
/// Richardson criterion |S2 - S1| <= 15 eps, eps halved per level), subdividing at least
/// `min_depth` times so that a peak narrower than the interval cannot fall between nodes.
fn simpson(f: &dyn Fn(f64) -> f64, a: f64, b: f64, eps: f64, min_depth: u32) -> f64 {
    fn rec(f: &dyn Fn(f64) -> f64, [a, b]: [f64; 2], fab: [f64; 3], whole: f64, eps: f64, depth: [u32; 2]) -> f64 {
        let [fa, fm, fb] = fab;
        let [depth, min_depth] = depth;
        let m = 0.5 * (a + b);
        let (flm, frm) = (f(0.5 * (a + m)), f(0.5 * (m + b)));
        let left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
        let right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
        let delta = left + right - whole;
        if depth >= 24 || (depth >= min_depth && delta.abs() <= 15.0 * eps) {
            return left + right + delta / 15.0;
        }
        rec(f, [a, m], [fa, flm, fm], left, 0.5 * eps, [depth + 1, min_depth]) + rec(f, [m, b], [fm, frm, fb], right, 0.5 * eps, [depth + 1, min_depth])
    }
    let (fa, fm, fb) = (f(a), f(0.5 * (a + b)), f(b));
    rec(f, [a, b], [fa, fm, fb], (b - a) / 6.0 * (fa + 4.0 * fm + fb), eps, [0, min_depth])
}

/// Pearson's chi-square statistic and p-value of `observed` against `expected` counts
/// (same total), pooling the categories with expected count below 5 (smallest first) as
/// pbrt's and Mitsuba's BSDF tests do, so that the chi-square approximation holds.
fn chi2_test(observed: &[f64], expected: &[f64]) -> (f64, usize, f64) {
    let mut order: Vec<usize> = (0..expected.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut pooled_obs, mut pooled_exp) = (0.0, 0.0);
    let (mut stat, mut cells) = (0.0, 0usize);
    for i in order {
        if expected[i] <= 0.0 && observed[i] > 0.0 {
            // A sample where the pdf says none can be: certain failure.
            return (f64::INFINITY, 0, 0.0);
        }
        if expected[i] < 5.0 || (pooled_exp > 0.0 && pooled_exp < 5.0) {
            pooled_obs += observed[i];
            pooled_exp += expected[i];
        } else {
            stat += (observed[i] - expected[i]).powi(2) / expected[i];
            cells += 1;
        }
    }
    if pooled_exp > 0.0 {
        stat += (pooled_obs - pooled_exp).powi(2) / pooled_exp;
        cells += 1;
    }
    // The counts sum to the sample count: one constraint.
    let dof = cells.saturating_sub(1).max(1);
    (stat, dof, gamma_q(0.5 * dof as f64, 0.5 * stat))
}

const THETA_BINS: usize = 16;
const PHI_BINS: usize = 32;

/// The polar angle's bins: the upper hemisphere's THETA_BINS, and as many again below it
/// for a rough dielectric, whose samples fill the sphere.
fn theta_bins(m: &MaterialF64) -> usize {
    if m.rough_glass() {
        2 * THETA_BINS
    } else {
        THETA_BINS
    }
}

/// Expected fraction of samples per (theta, phi) cell of the local upper hemisphere (the
/// sphere for a rough dielectric): the integral of pdf sin(theta) over the cell, by nested
/// adaptive Simpson.
fn expected_fractions(m: &MaterialF64, wo_local: DVec3) -> Vec<f64> {
    let dt = 0.5 * PI / THETA_BINS as f64;
    let dp = 2.0 * PI / PHI_BINS as f64;
    // Node spacing at most alpha (the specular peak's angular half-width in wi is about
    // 1.3 alpha), so that adaptive refinement always sees the peak; a quarter of it for
    // rough glass, whose refracted lobe is narrower by about (η − 1)/η.
    let width = match m.kind {
        MATERIAL_PRINCIPLED | MATERIAL_CONDUCTOR | MATERIAL_CONDUCTOR_BECKMANN | MATERIAL_PLASTIC | MATERIAL_PLASTIC_BECKMANN => bsdf::alpha(m.roughness),
        MATERIAL_ROUGH_DIELECTRIC | MATERIAL_ROUGH_DIELECTRIC_BECKMANN => 0.25 * bsdf::alpha(m.roughness),
        _ => 1.0,
    };
    let depth = |extent: f64| ((extent / width).log2().ceil().max(2.0)) as u32;
    // 1e-9 per cell: the 512 cells add at most 5e-7 of the probability, under one expected
    // sample in 10^6, far below the chi-square's resolution (sqrt(5) at the pooling limit).
    let eps = 1e-9;
    let mut out = Vec::with_capacity(theta_bins(m) * PHI_BINS);
    for it in 0..theta_bins(m) {
        for ip in 0..PHI_BINS {
            let (p0, p1) = (ip as f64 * dp, (ip + 1) as f64 * dp);
            let inner = |theta: f64| {
                let (st, ct) = theta.sin_cos();
                let f = |phi: f64| {
                    let (sp, cp) = phi.sin_cos();
                    bsdf::pdf_local(m, wo_local, DVec3::new(st * cp, st * sp, ct))
                };
                st * simpson(&f, p0, p1, eps / dt, depth(dp * st.max(1e-3)))
            };
            out.push(simpson(&inner, it as f64 * dt, (it + 1) as f64 * dt, eps, depth(dt)));
        }
    }
    out
}

#[test]
fn gpu_samples_follow_bsdf_pdf() {
    const SAMPLES: u32 = 1_000_000;
    let base_color = [0.9, 0.6, 0.3];
    let mut materials = vec![Material { base_color, roughness: 0.5, metallic: 0.0, kind: MATERIAL_DIFFUSE, ior: 1.5, ..Default::default() }];
    for roughness in [0.1, 0.3, 0.7, 1.0] {
        for metallic in [0.0, 0.5, 1.0] {
            materials.push(Material { base_color, roughness, metallic, kind: MATERIAL_PRINCIPLED, ior: 1.5, ..Default::default() });
        }
    }
    // Principled dielectrics of other indices: no specular reflection at normal incidence
    // (1), and a reflectance of 0.17 (2.4).
    for ior in [1.0, 2.4] {
        for roughness in [0.1, 0.5] {
            materials.push(Material { base_color, roughness, metallic: 0.0, kind: MATERIAL_PRINCIPLED, ior, ..Default::default() });
        }
    }
    // Rough glass of both distributions from outside and from inside (total internal
    // reflection past 42°).
    for kind in [MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN] {
        for roughness in [0.3, 0.7] {
            for ior in [1.5, 1.0 / 1.5] {
                materials.push(Material { base_color, roughness, metallic: 0.0, kind, ior, ..Default::default() });
            }
        }
    }
    // Gold of both distributions.
    let [eta, k] = vkinverse::scene::metal("Au").unwrap();
    for kind in [MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN] {
        for roughness in [0.3, 0.7] {
            materials.push(Material { base_color, roughness, kind, eta, k, ..Default::default() });
        }
    }
    // Plastics: each coating, a dark and a bright base.
    for i in 0..COATINGS.len() {
        for base in [[0.05, 0.1, 0.02], base_color] {
            materials.push(plastic(i, base, [0, COATING_NONLINEAR, COATING_UNLAYERED, COATING_NONLINEAR][i]));
        }
    }
    // A tilted normal, so that the sampled frame is not the world frame.
    let n = DVec3::new(0.3, -0.5, 0.8).normalize();
    let theta_o_degrees = [5.0f64, 45.0, 80.0];
    let cases: Vec<(Material, f64)> = materials.iter().flat_map(|m| theta_o_degrees.iter().map(move |&t| (*m, t))).collect();
    // Family-wise significance 1 %, Šidák-corrected over the cases.
    let level = sidak(0.01, cases.len());

    let frame = ShadingFrame::new(n);
    let p_values = with_gpu(|ctx| {
        let pipe = ComputePipeline::new(ctx, "bsdf_sample_test", &[]).unwrap();
        let out = Buffer::zeroed::<[f32; 3]>(ctx, "samples", SAMPLES as usize, MemoryKind::Readback).unwrap();
        let tables = Buffer::from_slice(ctx, "tables", &coating_tables().0, MemoryKind::Upload).unwrap();
        let group = pipe.bind(&[("Samples", &out), ("Tables", &tables)]).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "bsdf_sample_test").unwrap();
        let mut p_values = Vec::new();
        for (case, (material, theta_o)) in cases.iter().enumerate() {
            let wo = direction(n, theta_o.to_radians().cos(), 0.7);
            let push = SamplePush { material: *material, n: f3(n), wo: f3(wo), count: SAMPLES, seed: case as u32 * 7919 + 1 };
            cmd.record(|rec| rec.dispatch_linear(&pipe, &group, &push, SAMPLES as u64)).unwrap();
            cmd.submit_and_wait().unwrap();
            let samples: Vec<[f32; 3]> = out.read().unwrap();

            // Observed counts per cell, plus one category for failed samples.
            let m = mirror(*material);
            let bins = theta_bins(&m);
            let mut observed = vec![0.0; bins * PHI_BINS + 1];
            for s in &samples {
                let w = v3(*s);
                if w == DVec3::ZERO {
                    observed[bins * PHI_BINS] += 1.0;
                    continue;
                }
                let l = frame.to_local(w.normalize());
                assert!(l.z > 0.0 || m.rough_glass(), "a sample below the surface was returned as valid: {l}");
                let theta = l.z.clamp(-1.0, 1.0).acos();
                let phi = l.y.atan2(l.x).rem_euclid(2.0 * PI);
                let it = ((theta / (0.5 * PI) * THETA_BINS as f64) as usize).min(bins - 1);
                let ip = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
                observed[it * PHI_BINS + ip] += 1.0;
            }
            let fractions = expected_fractions(&m, frame.to_local(v3(f3(wo))));
            let total: f64 = fractions.iter().sum();
            assert!(total <= 1.0 + 1e-6, "pdf integrates to {total} > 1");
            let mut expected: Vec<f64> = fractions.iter().map(|f| f * SAMPLES as f64).collect();
            expected.push((1.0 - total).max(0.0) * SAMPLES as f64);
            let (stat, dof, p) = chi2_test(&observed, &expected);
            println!(
                "kind {} roughness {} metallic {} ior {} theta_o {theta_o}: chi2 {stat:.1} dof {dof} p {p:.4} (pdf mass {total:.5}, failed {})",
                material.kind,
                material.roughness,
                material.metallic,
                material.ior,
                observed[bins * PHI_BINS]
            );
            p_values.push((p, format!("{material:?} theta_o {theta_o}: chi2 {stat:.1}, {dof} dof")));
        }
        p_values
    });
    let min = p_values.iter().map(|p| p.0).fold(1.0, f64::min);
    let max = p_values.iter().map(|p| p.0).fold(0.0, f64::max);
    println!("p-values in [{min:.4}, {max:.4}], per-case level {level:.2e}");
    let rejected: Vec<_> = p_values.iter().filter(|p| p.0 < level).map(|p| format!("p = {:.2e}: {}", p.0, p.1)).collect();
    assert!(rejected.is_empty(), "samples do not follow bsdf_pdf:\n{}", rejected.join("\n"));
}

// ---------------------------------------------------------------------------------------
// (c) energy: the BSDF alone in a white furnace reflects at most what it receives
// ---------------------------------------------------------------------------------------

#[test]
fn white_furnace_albedo_is_at_most_one() {
    // Albedo(wo) = integral of f cos over wi, estimated as the mean weight of bsdf_sample
    // (the chi-square test shows that the samples follow bsdf_pdf, and the weights are
    // eval / pdf). base_color = 1 is the worst case: every term grows with it.
    const SAMPLES: usize = 100_000;
    let mut cases = vec![MaterialF64 { base_color: DVec3::ONE, roughness: 0.5, metallic: 0.0, kind: MATERIAL_DIFFUSE, ior: 1.5, ..Default::default() }];
    for roughness in [0.0, 0.1, 0.3, 0.5, 0.7, 1.0] {
        for metallic in [0.0, 0.5, 1.0] {
            cases.push(MaterialF64 { base_color: DVec3::ONE, roughness, metallic, kind: MATERIAL_PRINCIPLED, ior: 1.5, ..Default::default() });
        }
    }
    // White principled dielectrics of other indices, from no reflectance at normal
    // incidence (1) to 0.36 (4).
    for ior in [1.0, 1.2, 2.4, 4.0] {
        for roughness in [0.0, 0.3, 1.0] {
            cases.push(MaterialF64 { base_color: DVec3::ONE, roughness, metallic: 0.0, kind: MATERIAL_PRINCIPLED, ior, ..Default::default() });
        }
    }
    // Rough glass, its radiance through the interface counted as power (times η², undoing
    // the solid angle's compression), from outside and inside.
    for kind in [MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN] {
        for roughness in [0.0, 0.1, 0.3, 0.7, 1.0] {
            for ior in [1.5, 1.0 / 1.5] {
                cases.push(MaterialF64 { base_color: DVec3::ONE, roughness, metallic: 0.0, kind, ior, ..Default::default() });
            }
        }
    }
    // A perfect conductor (reflectance 1 at every angle: eta 0, k 1).
    for kind in [MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN] {
        for roughness in [0.0, 0.1, 0.3, 0.7, 1.0] {
            cases.push(MaterialF64 { base_color: DVec3::ONE, roughness, kind, k: DVec3::ONE, ..Default::default() });
        }
    }
    // White plastics: their coating's reflection and the base's light that comes back out.
    for i in 0..COATINGS.len() {
        for flags in [0, COATING_NONLINEAR, COATING_UNLAYERED] {
            cases.push(mirror(plastic(i, [1.0; 3], flags)));
        }
    }
    let cos_o = [1.0, 0.7, 0.3, 0.1, 0.01];
    // One-sided test of "albedo <= 1" per case at family-wise level 1 % (Šidák): reject
    // when the mean exceeds 1 by more than z standard errors. A smooth white metal has
    // weight G2 / G1 <= 1 for every sample (standard error 0), so f64 rounding of the
    // weights (~1e-15 relative) gets its own allowance of 1e-12.
    let z = normal_quantile_upper(sidak(0.01, cases.len() * cos_o.len()));
    let n = DVec3::new(-0.2, 0.4, 0.9).normalize();
    let mut rng = Rng(5);
    let mut worst = (0.0f64, String::new());
    for m in &cases {
        for &c in &cos_o {
            let wo = direction(n, c, 1.3);
            let (mut sum, mut sum2) = (0.0, 0.0);
            for _ in 0..SAMPLES {
                let u = DVec3::new(rng.f64(), rng.f64(), rng.f64());
                if let Some(s) = bsdf::sample(m, n, wo, u) {
                    // Grey material: the three channels are equal.
                    assert!((s.weight.x - s.weight.z).abs() <= 1e-12 * s.weight.x.abs());
                    let w = if s.wi.dot(n) < 0.0 { s.weight.x * m.ior * m.ior } else { s.weight.x };
                    sum += w;
                    sum2 += w * w;
                }
            }
            let mean = sum / SAMPLES as f64;
            let se = ((sum2 / SAMPLES as f64 - mean * mean).max(0.0) / (SAMPLES as f64 - 1.0)).sqrt();
            let label = format!("kind {} roughness {} metallic {} cos_o {c}: albedo {mean:.4} +- {se:.4}", m.kind, m.roughness, m.metallic);
            if m.kind == MATERIAL_PRINCIPLED && mean > worst.0 {
                worst = (mean, label.clone());
            }
            assert!(mean - z * se <= 1.0 + 1e-12, "energy gain: {label} (z = {z:.2})");
            // Nearly smooth glass or metal loses almost nothing (a single-scattering microfacet model
            // loses what scatters more than once between microfacets, which grows with
            // the roughness): a wrong Jacobian or η² would show here.
            if (m.rough_glass() || m.conductor()) && m.roughness <= 0.1 && c >= 0.3 {
                assert!(mean + z * se >= 0.99, "energy loss: {label}");
            }
        }
    }
    println!("largest principled albedo: {}", worst.1);
}

// ---------------------------------------------------------------------------------------
// (d) eval_grad against central finite differences of eval (the GPU's eval_grad is
// compared with the mirror's in gpu_matches_cpu_mirror)
// ---------------------------------------------------------------------------------------

#[test]
fn eval_grad_matches_finite_differences() {
    let mut rng = Rng(11);
    let h = 1e-5;
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for i in 0..3000 {
        let r = rng.f64();
        let mt = rng.f64();
        let m = MaterialF64 {
            base_color: DVec3::new(rng.f64(), rng.f64(), rng.f64()),
            roughness: rng.pick(&[0.0, 0.01, 0.05, 1.0, r, r, r]),
            metallic: rng.pick(&[0.0, 1.0, mt, mt]),
            kind: match i % 10 {
                0 => MATERIAL_DIFFUSE,
                3 => MATERIAL_ROUGH_DIELECTRIC,
                7 => MATERIAL_ROUGH_DIELECTRIC_BECKMANN,
                5 => MATERIAL_CONDUCTOR,
                9 => MATERIAL_CONDUCTOR_BECKMANN,
                _ => MATERIAL_PRINCIPLED,
            },
            // Glass from outside and inside; for the principled model, dielectric
            // reflectances from 0.008 to 0.17.
            ior: match i % 8 {
                3 | 7 => 1.0 / 1.5,
                1 => 2.4,
                5 => 1.2,
                _ => 1.5,
            },
            eta: DVec3::new(rng.range(0.0, 4.0), rng.range(0.0, 4.0), rng.range(0.0, 4.0)),
            k: DVec3::new(rng.range(0.0, 8.0), rng.range(0.0, 8.0), rng.range(0.0, 8.0)),
            ..Default::default()
        };
        // Every sixth case a plastic of one of the coatings, linear or not, at the random
        // base colour.
        let m = if i % 6 == 1 {
            let b = m.base_color.as_vec3().to_array();
            mirror(plastic(rng.next_u64() as usize % COATINGS.len(), b, coating_flags(rng.f64())))
        } else {
            m
        };
        let n = rng.unit_vector();
        let wo = direction(n, rng.range(0.01, 1.0), rng.range(0.0, 2.0 * PI));
        // Rough glass: half of its directions below the surface (its transmission).
        let below = m.rough_glass() && rng.f64() < 0.5;
        let wi = if rng.f64() < 0.3 && !below {
            let mirror = 2.0 * wo.dot(n) * n - wo;
            (mirror + 0.1 * rng.unit_vector()).normalize()
        } else {
            direction(n, if below { -rng.range(0.01, 1.0) } else { rng.range(0.01, 1.0) }, rng.range(0.0, 2.0 * PI))
        };
        if ShadingFrame::new(n).to_local(wi).z <= 0.0 && !below {
            continue;
        }
        // The stencil must not straddle the kink of alpha = max(r^2, ALPHA_MIN).
        let (lo, hi) = (m.roughness - 2.0 * h, m.roughness + 2.0 * h);
        let straddles = lo > 0.0 && lo * lo < ALPHA_MIN && hi * hi > ALPHA_MIN;
        let g = bsdf::eval_grad(&m, n, wo, wi);
        type Shifted = Box<dyn Fn(f64) -> MaterialF64>;
        // (parameter, analytic derivative of the three channels, material with it shifted)
        let params: [(&str, DVec3, Shifted); 5] = [
            ("base_color.r", DVec3::new(g.d_base_color.x, 0.0, 0.0), Box::new(move |d| MaterialF64 { base_color: m.base_color + DVec3::X * d, ..m })),
            ("base_color.g", DVec3::new(0.0, g.d_base_color.y, 0.0), Box::new(move |d| MaterialF64 { base_color: m.base_color + DVec3::Y * d, ..m })),
            ("base_color.b", DVec3::new(0.0, 0.0, g.d_base_color.z), Box::new(move |d| MaterialF64 { base_color: m.base_color + DVec3::Z * d, ..m })),
            ("roughness", g.d_roughness, Box::new(move |d| MaterialF64 { roughness: m.roughness + d, ..m })),
            ("metallic", g.d_metallic, Box::new(move |d| MaterialF64 { metallic: m.metallic + d, ..m })),
        ];
        for (name, analytic, at) in params {
            // A plastic's roughness is no parameter (its table is fixed for it).
            if name == "roughness" && (straddles || m.plastic()) {
                continue;
            }
            let v = |d: f64| bsdf::eval(&at(d), n, wo, wi);
            let (p1, m1, p2, m2) = (v(h), v(-h), v(2.0 * h), v(-2.0 * h));
            let fd1 = (p1 - m1) / (2.0 * h);
            let fd2 = (p2 - m2) / (4.0 * h);
            for c in 0..3 {
                // Central differences err by c h^2 + O(h^4): fd2 - fd1 ~ 3 c h^2 estimates
                // that error, and 2 |fd2 - fd1| bounds it with margin. Rounding adds about
                // (f64 epsilon x the ~100 operations of eval) |v| / h.
                let scale = p1[c].abs().max(m1[c].abs()).max(p2[c].abs()).max(m2[c].abs());
                let tol = 2.0 * (fd2[c] - fd1[c]).abs() + 100.0 * f64::EPSILON * scale / h;
                let err = (analytic[c] - fd1[c]).abs();
                assert!(
                    err <= tol,
                    "d value[{c}] / d {name}: analytic {} vs finite difference {} (tol {tol:e}); {m:?} n {n} wo {wo} wi {wi}",
                    analytic[c],
                    fd1[c]
                );
                if fd1[c] != 0.0 {
                    worst = worst.max(err / fd1[c].abs());
                }
                checked += 1;
            }
        }
    }
    println!("{checked} derivatives checked; largest relative difference {worst:.2e}");
    assert!(checked > 30_000);
}

// ---------------------------------------------------------------------------------------
// (e) reciprocity, and the sample's pdf and weight against bsdf_pdf and bsdf_eval
// ---------------------------------------------------------------------------------------

#[test]
fn principled_conductor_and_plastic_are_reciprocal() {
    // The diffuse Fresnel factor (1 - F_d(cos_o)) (1 - F_d(cos_i)) is symmetric, so the
    // whole model, not only its specular part, must be reciprocal. Both orders use the
    // same half vector (wo + wi is commutative) and sums and products of positive terms,
    // so they differ by rounding: ~30 operations, under 100 epsilons. One term is computed
    // differently: the Fresnel cosine, wo.h against wi.h. They are equal for the exact h,
    // but the rounded h is off by ~2 eps / |wo + wi| per component, which changes
    // (wo - wi).h by up to ~4 eps / |wo + wi|, and the fifth power in Schlick's weight
    // multiplies that by 5 (near retro-reflection, where it matters, 1 - wo.h ~ 1).
    // Allowed: eps (100 + 50 / |wo + wi|). The conductor's terms are alike (its masking
    // G1(wo) G1(wi), its complex Fresnel term at wo.h or wi.h), but that Fresnel term can
    // amplify the cosine's rounding more than Schlick's fifth power does (up to ~4e-14
    // seen, with eta near 0): 1e-12 is allowed there, far below any wrong factor.
    let mut rng = Rng(3);
    let mut worst: f64 = 0.0;
    for case in 0..20_000 {
        let (r, mt) = (rng.f64(), rng.f64());
        let m = MaterialF64 {
            base_color: DVec3::new(rng.f64(), rng.f64(), rng.f64()),
            roughness: rng.pick(&[0.0, 0.05, 1.0, r, r]),
            metallic: rng.pick(&[0.0, 1.0, mt]),
            kind: rng.pick(&[MATERIAL_PRINCIPLED, MATERIAL_PRINCIPLED, MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_PLASTIC]),
            // (A principled material's index is set below: a plastic's must stay its table's.)
            ior: 1.5,
            eta: DVec3::new(rng.range(0.0, 4.0), rng.range(0.0, 4.0), rng.range(0.0, 4.0)),
            k: DVec3::new(rng.range(0.0, 8.0), rng.range(0.0, 8.0), rng.range(0.0, 8.0)),
            ..Default::default()
        };
        // (By the case's number, not a draw, so that the other kinds' cases stay as they were.)
        let ior = [1.0, 1.2, 1.5, 2.4, 4.0][case % 5];
        let m = if m.kind == MATERIAL_PRINCIPLED { MaterialF64 { ior, ..m } } else { m };
        let m = if m.kind == MATERIAL_PLASTIC {
            mirror(plastic(rng.next_u64() as usize % COATINGS.len(), m.base_color.as_vec3().to_array(), coating_flags(rng.f64())))
        } else {
            m
        };
        let n = rng.unit_vector();
        let cos = |rng: &mut Rng| if rng.f64() < 0.2 { 10f64.powf(rng.range(-3.0, -1.0)) } else { rng.f64() };
        let wo = direction(n, cos(&mut rng), rng.range(0.0, 2.0 * PI));
        let wi = direction(n, cos(&mut rng), rng.range(0.0, 2.0 * PI));
        let frame = ShadingFrame::new(n);
        let (co, ci) = (frame.to_local(wo).z, frame.to_local(wi).z);
        if co <= 0.0 || ci <= 0.0 {
            continue;
        }
        let f_oi = bsdf::eval(&m, n, wo, wi) / ci;
        let f_io = bsdf::eval(&m, n, wi, wo) / co;
        let tol = if m.conductor() || m.plastic() { 1e-12 } else { f64::EPSILON * (100.0 + 50.0 / (wo + wi).length()) };
        for c in 0..3 {
            // (Far from Beckmann's peak the value leaves f64's normal range, and its digits.)
            if f_oi[c].abs() < 1e-250 {
                assert!(f_io[c].abs() < 1e-240, "f(wo, wi) = {f_oi} but f(wi, wo) = {f_io}");
                continue;
            }
            let rel = (f_oi[c] - f_io[c]).abs() / f_oi[c].abs();
            worst = worst.max(rel / tol);
            assert!(rel <= tol, "f(wo, wi) = {f_oi} but f(wi, wo) = {f_io}: {m:?} n {n} wo {wo} wi {wi}");
        }
    }
    println!("largest relative asymmetry / tolerance: {worst:.3}");
}

/// Rough glass obeys the reciprocity of a BSDF between media (Veach 1997, eq. 5.15): its
/// reflection is symmetric, and with radiance's 1/η² its transmission seen from wi's side
/// (the normal flipped, the relative index inverted) is η² times the one seen from wo's,
/// f(wi → wo; 1/η) = η² f(wo → wi; η). Both orders compute the same terms in another
/// order (h from wo + η wi against wi + wo / η, normalised; the Fresnel term from either
/// side): rounding, which the Fresnel term's square root amplifies near the critical
/// angle (1.4e-8 seen there), so 1e-6 is allowed; a wrong factor would be far larger.
#[test]
fn rough_dielectric_is_reciprocal() {
    let mut rng = Rng(23);
    let (mut reflected, mut transmitted) = (0, 0);
    for _ in 0..20_000 {
        let r = rng.f64();
        let ior = rng.pick(&[1.5, 1.0 / 1.5, 1.33, 0.5 + 2.0 * r]);
        let m = MaterialF64 {
            base_color: DVec3::new(rng.f64(), rng.f64(), rng.f64()),
            roughness: rng.pick(&[0.05, 1.0, r, r]),
            metallic: 0.0,
            kind: rng.pick(&[MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN]),
            ior,
            ..Default::default()
        };
        let back = MaterialF64 { ior: 1.0 / ior, ..m };
        let n = rng.unit_vector();
        let wo = direction(n, rng.range(0.01, 1.0), rng.range(0.0, 2.0 * PI));
        let below = rng.f64() < 0.6;
        let wi = direction(n, if below { -rng.range(0.01, 1.0) } else { rng.range(0.01, 1.0) }, rng.range(0.0, 2.0 * PI));
        let (co, ci) = (wo.dot(n), wi.dot(n).abs());
        let forward = bsdf::eval(&m, n, wo, wi) / ci;
        let (reverse, scale) = if below { (bsdf::eval(&back, -n, wi, wo) / co, ior * ior) } else { (bsdf::eval(&m, n, wi, wo) / co, 1.0) };
        if forward == DVec3::ZERO {
            assert_eq!(reverse, DVec3::ZERO, "one order has a value, the other none: {m:?} n {n} wo {wo} wi {wi}");
            continue;
        }
        for c in 0..3 {
            // (Far from Beckmann's peak the value leaves f64's normal range, and its digits.)
            if scale * forward[c] < 1e-250 {
                assert!(reverse[c] < 1e-240, "f(wi, wo) = {reverse} but {scale} f(wo, wi) = {}", scale * forward);
                continue;
            }
            let rel = (reverse[c] - scale * forward[c]).abs() / (scale * forward[c]).abs();
            assert!(rel <= 1e-6, "f(wi, wo) = {reverse} but {scale} f(wo, wi) = {}: {m:?} n {n} wo {wo} wi {wi}", scale * forward);
        }
        if below {
            transmitted += 1
        } else {
            reflected += 1
        }
    }
    // A direction below the surface has a value only where a microfacet refracts wo into
    // it without being seen from behind (about a fifth of the uniform ones drawn here).
    println!("{reflected} reflections and {transmitted} transmissions compared");
    assert!(reflected > 5_000 && transmitted > 1_500);
}

#[test]
fn sample_pdf_and_weight_match_pdf_and_eval() {
    // bsdf_sample evaluates at the microfacet normal it drew, bsdf_pdf and bsdf_eval at
    // normalize(wo + wi); in f64 the two normals differ by ~1e-16, which moves D by at
    // most 4 (1e-16 / t) relative for a tangential part t >= 1e-4 of h (alpha >= 1e-3 and
    // samples within a few alpha of the peak): 1e-11, so 1e-9 is a safe bound.
    let mut rng = Rng(17);
    let mut count = 0;
    for i in 0..20_000 {
        let (r, mt) = (rng.f64(), rng.f64());
        let m = MaterialF64 {
            base_color: DVec3::new(rng.f64(), rng.f64(), rng.f64()),
            roughness: rng.pick(&[0.0, 0.05, 1.0, r, r]),
            metallic: rng.pick(&[0.0, 1.0, mt]),
            kind: match i % 10 {
                0 => MATERIAL_DIFFUSE,
                5 => MATERIAL_ROUGH_DIELECTRIC,
                6 => MATERIAL_ROUGH_DIELECTRIC_BECKMANN,
                3 => MATERIAL_CONDUCTOR,
                8 => MATERIAL_CONDUCTOR_BECKMANN,
                _ => MATERIAL_PRINCIPLED,
            },
            ior: if i % 20 >= 10 { 1.0 / 1.5 } else { 1.5 },
            eta: DVec3::new(rng.range(0.0, 4.0), rng.range(0.0, 4.0), rng.range(0.0, 4.0)),
            k: DVec3::new(rng.range(0.0, 8.0), rng.range(0.0, 8.0), rng.range(0.0, 8.0)),
            ..Default::default()
        };
        let m = if i % 10 == 9 {
            mirror(plastic(i / 10 % COATINGS.len(), m.base_color.as_vec3().to_array(), [0, COATING_NONLINEAR, COATING_UNLAYERED][i / 10 % 3]))
        } else {
            m
        };
        let n = rng.unit_vector();
        let wo = direction(n, rng.range(0.0, 1.0), rng.range(0.0, 2.0 * PI));
        let u = DVec3::new(rng.f64(), rng.f64(), rng.f64());
        let Some(s) = bsdf::sample(&m, n, wo, u) else { continue };
        let pdf = bsdf::pdf(&m, n, wo, s.wi);
        let value = bsdf::eval(&m, n, wo, s.wi);
        assert!((s.pdf - pdf).abs() <= 1e-9 * pdf, "sample pdf {} vs bsdf_pdf {pdf}: {m:?}", s.pdf);
        let w = value / pdf;
        for c in 0..3 {
            assert!((s.weight[c] - w[c]).abs() <= 1e-9 * w[c].abs() + 1e-300, "weight {} vs eval / pdf {w}: {m:?}", s.weight);
        }
        count += 1;
    }
    assert!(count > 15_000);
}

/// The smooth dielectric's lobes against optics: Fresnel's reflectance at normal incidence
/// and at Brewster's angle, total internal reflection past the critical angle, Snell's
/// law and the plane of incidence for the refraction, the mirror for the reflection, the
/// refracted radiance's 1/η² and the lobe probabilities' sum.
#[test]
fn dielectric_follows_snell_and_fresnel() {
    let glass =
        |ior: f64| MaterialF64 { base_color: DVec3::new(1.0, 0.5, 0.25), roughness: 0.0, metallic: 0.0, kind: MATERIAL_DIELECTRIC, ior, ..Default::default() };
    let n = DVec3::new(0.0, 0.6, 0.8);
    for eta in [1.5, 1.33, 1.0 / 1.5, 2.4] {
        // Normal incidence: ((η − 1)/(η + 1))², whichever side.
        let (f, cos_t) = bsdf::dielectric_fresnel(1.0, eta);
        let expected = ((eta - 1.0) / (eta + 1.0)).powi(2);
        assert!((f - expected).abs() < 1e-12 && (cos_t - 1.0).abs() < 1e-12, "η {eta}: F(0) {f} against {expected}");
        // Brewster's angle tan θ = η: the p-polarised part vanishes, F = rs²/2.
        let theta_b = eta.atan();
        let (f, cos_t) = bsdf::dielectric_fresnel(theta_b.cos(), eta);
        let rs = (theta_b.cos() - eta * cos_t) / (theta_b.cos() + eta * cos_t);
        assert!((f - 0.5 * rs * rs).abs() < 1e-12, "η {eta}: F at Brewster's angle {f}");
        for k in 1..40 {
            let theta_i = k as f64 / 40.0 * std::f64::consts::FRAC_PI_2;
            let wo = direction(n, theta_i.cos(), 0.3 * k as f64);
            let m = glass(eta);
            let (f, cos_t) = bsdf::dielectric_fresnel(theta_i.cos(), eta);
            let critical = eta < 1.0 && theta_i.sin() >= eta;
            if critical {
                assert_eq!((f, cos_t), (1.0, 0.0), "η {eta}, θ {theta_i}: total internal reflection");
            } else {
                assert!(f > 0.0 && f < 1.0, "η {eta}, θ {theta_i}: F {f}");
            }
            // The mirror, probability F, weight 1.
            let r = bsdf::dielectric_sample(&m, n, wo, 0.0).unwrap();
            assert!((r.wi - (2.0 * wo.dot(n) * n - wo)).length() < 1e-12 && r.weight == DVec3::ONE && (r.pdf - f).abs() < 1e-12);
            let t = bsdf::dielectric_sample(&m, n, wo, 1.0 - 1e-12);
            if critical {
                assert!(t.as_ref().is_some_and(|t| t.wi.dot(n) > 0.0), "η {eta}, θ {theta_i}: only the mirror past the critical angle");
                continue;
            }
            let t = t.unwrap();
            // Snell: sin θ_t = sin θ_i / η, below the surface, in the plane of incidence,
            // the tangential part opposite wo's.
            let sin_t = t.wi.cross(n).length();
            assert!((t.wi.length() - 1.0).abs() < 1e-12 && t.wi.dot(n) < 0.0);
            assert!((sin_t - theta_i.sin() / eta).abs() < 1e-9, "η {eta}, θ {theta_i}: sin θ_t {sin_t}");
            assert!(t.wi.dot(wo.cross(n)).abs() < 1e-12, "out of the plane of incidence");
            let (wo_t, wi_t) = (wo - wo.dot(n) * n, t.wi - t.wi.dot(n) * n);
            assert!(wo_t.dot(wi_t) <= 1e-15);
            // Probability 1 − F, weight base_color / η², and the mass their product.
            assert!((t.pdf - (1.0 - f)).abs() < 1e-12 && (r.pdf + t.pdf - 1.0).abs() < 1e-12);
            assert!((t.weight - m.base_color / (eta * eta)).length() < 1e-12);
            assert!((bsdf::dielectric_mass(&m, n, wo, t.wi) - t.weight * t.pdf).length() < 1e-12);
            assert!((bsdf::dielectric_mass(&m, n, wo, r.wi) - DVec3::splat(f)).length() < 1e-12);
            // Radiance through the interface and back (η, then 1/η at the same angles)
            // keeps its transmittance's product only: the solid-angle factors cancel.
            let back = glass(1.0 / eta);
            let round = bsdf::dielectric_mass(&m, n, wo, t.wi) * bsdf::dielectric_mass(&back, -n, t.wi, wo);
            let (f_back, _) = bsdf::dielectric_fresnel(-t.wi.dot(n), 1.0 / eta);
            assert!((f_back - f).abs() < 1e-9, "η {eta}, θ {theta_i}: the Fresnel reflectance is the same from both sides ({f}, {f_back})");
            assert!((round - m.base_color * m.base_color * (1.0 - f) * (1.0 - f_back)).length() < 1e-9);
            // The generic functions see no lobe (delta lobes are not light-sampled).
            assert_eq!(bsdf::eval(&m, n, wo, r.wi), DVec3::ZERO);
            assert_eq!(bsdf::pdf(&m, n, wo, r.wi), 0.0);
        }
    }
}

/// The thin dielectric: a sheet that mirrors with 2F/(1 + F), the sum of its two faces'
/// reflections over every internal round trip (F + (1 − F)² F Σ F^2k), and lets the rest
/// through unbent, tinted once and without the interface's 1/η².
#[test]
fn thin_dielectric_sums_its_internal_reflections() {
    let n = DVec3::new(0.0, 0.6, 0.8);
    let sheet =
        MaterialF64 { base_color: DVec3::new(1.0, 0.5, 0.25), roughness: 0.0, metallic: 0.0, kind: MATERIAL_THIN_DIELECTRIC, ior: 1.5, ..Default::default() };
    for k in 0..40 {
        let theta = k as f64 / 40.0 * std::f64::consts::FRAC_PI_2;
        let wo = direction(n, theta.cos(), 0.7 * k as f64);
        let (f, _) = bsdf::dielectric_fresnel(theta.cos(), 1.5);
        let series = f + (1.0 - f) * (1.0 - f) * f * (0..200).map(|j| f.powi(2 * j)).sum::<f64>();
        let r = bsdf::dielectric_sample(&sheet, n, wo, 0.0).unwrap();
        assert!((r.pdf - series).abs() < 1e-12, "θ {theta}: R {} against the series {series}", r.pdf);
        let t = bsdf::dielectric_sample(&sheet, n, wo, 1.0 - 1e-12).unwrap();
        assert_eq!(t.wi, -wo);
        assert!((t.pdf - (1.0 - series)).abs() < 1e-12 && t.weight == sheet.base_color);
        assert!((bsdf::dielectric_mass(&sheet, n, wo, t.wi) - sheet.base_color * (1.0 - series)).length() < 1e-12);
    }
}

/// A plastic's coating tables against the interface they stand for: the transmittance and
/// reflectance that `bsdf::coating_albedo` integrates over visible normals, against a
/// direct integral of the rough dielectric's BSDF (the same interface, `bsdf::eval`) over
/// a grid of directions, for both distributions, from outside and from inside (total
/// internal reflection); a nearly smooth coating against Fresnel's equations; and the
/// tables' internal reflectance against its definition.
#[test]
fn plastic_coatings_integrate_their_interface() {
    // The rough dielectric's transmission carries radiance's 1/η², which the coating's
    // albedo (power) does not: η² times the integral. Its masking is Smith's G1(wo) G1(wi)
    // with Walter et al.'s approximation for Beckmann, where the visible normals follow
    // the exact G1(wo): 1 % is allowed for that and the grid.
    let direct = |beckmann: bool, alpha: f64, eta: f64, mu: f64| {
        let m = MaterialF64 {
            base_color: DVec3::ONE,
            roughness: alpha.sqrt(),
            kind: if beckmann { MATERIAL_ROUGH_DIELECTRIC_BECKMANN } else { MATERIAL_ROUGH_DIELECTRIC },
            ior: eta,
            ..Default::default()
        };
        let wo = DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
        let n = 600;
        let (mut r, mut t) = (0.0, 0.0);
        for a in 0..n {
            let theta = (a as f64 + 0.5) / n as f64 * PI;
            for b in 0..n {
                let phi = (b as f64 + 0.5) / n as f64 * 2.0 * PI;
                let wi = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
                let v = bsdf::eval_local(&m, wo, wi).x * theta.sin() * (PI / n as f64) * (2.0 * PI / n as f64);
                if wi.z > 0.0 {
                    r += v
                } else {
                    t += v * eta * eta
                }
            }
        }
        (r, t)
    };
    for (beckmann, alpha, eta, mu) in
        [(false, 0.3, 1.5, 0.7), (true, 0.5, 1.5, 0.95), (false, 0.5, 1.0 / 1.5, 0.9), (true, 0.3, 1.0 / 1.33, 0.4), (true, 0.25, 1.49, 0.2)]
    {
        let (r, t) = (bsdf::coating_albedo(beckmann, alpha, eta, mu, false), bsdf::coating_albedo(beckmann, alpha, eta, mu, true));
        let (rb, tb) = direct(beckmann, alpha, eta, mu);
        println!("beckmann {beckmann} alpha {alpha} eta {eta:.3} mu {mu}: R {r:.5} (direct {rb:.5}), T {t:.5} (direct {tb:.5})");
        assert!(r + t <= 1.0 + 1e-9, "R + T = {}", r + t);
        assert!(
            (r - rb).abs() < 0.01 * rb.max(0.02) && (t - tb).abs() < 0.01 * tb.max(0.02),
            "beckmann {beckmann} alpha {alpha} eta {eta} mu {mu}: R {r} against {rb}, T {t} against {tb}"
        );
    }
    // Nearly smooth (alpha 1e-3): Fresnel's reflectance F and 1 − F, from outside and from
    // inside (where past the critical angle everything comes back).
    for (mu, eta) in [(1.0, 1.5), (0.3, 1.5), (0.05, 1.33), (0.9, 1.0 / 1.5), (0.5, 1.0 / 1.5)] {
        let f = bsdf::dielectric_fresnel(mu, eta).0;
        for beckmann in [false, true] {
            let (r, t) = (bsdf::coating_albedo(beckmann, ALPHA_MIN, eta, mu, false), bsdf::coating_albedo(beckmann, ALPHA_MIN, eta, mu, true));
            assert!((r - f).abs() < 2e-3 && (t - (1.0 - f)).abs() < 2e-3, "mu {mu} eta {eta}: R {r} T {t} against F {f}");
        }
    }
    // The table: T at μ = i / 63, and the internal reflectance as the sum over the same μ.
    let (table, internal) = bsdf::coating(true, 0.1f64.sqrt(), 1.49);
    let a = bsdf::alpha(0.1f64.sqrt());
    let mu = |i: usize| (i as f64 / 63.0).max(1e-6);
    for i in [0, 20, 63] {
        assert_eq!(table[i], bsdf::coating_albedo(true, a, 1.49, mu(i), true));
    }
    let sum: f64 = (0..64).map(|i| bsdf::coating_albedo(true, a, 1.0 / 1.49, mu(i), false) * mu(i)).sum();
    assert!((internal - sum / 32.0).abs() < 1e-15);
    // A smooth coating (roughness 0 or up to the smallest alpha) is Mitsuba's smooth
    // plastic's: 1 − F, and the fit of the internal reflectance.
    for roughness in [0.0, 0.03] {
        let (table, internal) = bsdf::coating(false, roughness, 1.5);
        assert_eq!(table[63], 1.0 - bsdf::dielectric_fresnel(1.0, 1.5).0);
        assert_eq!(internal, bsdf::fresnel_diffuse_reflectance(1.0 / 1.5));
    }
    // The fits against their defining integral 2 ∫ F(μ, η) μ dμ (midpoint rule, 10^5 points):
    // within 0.2 % (0.1 % at most measured, over η in [0.67, 1.9]).
    for eta in [1.0 / 1.5, 1.0 / 1.33, 1.33, 1.5, 1.9] {
        let n = 100_000;
        let exact: f64 = (0..n).map(|i| (i as f64 + 0.5) / n as f64).map(|m| 2.0 * bsdf::dielectric_fresnel(m, eta).0 * m / n as f64).sum();
        let fit = bsdf::fresnel_diffuse_reflectance(eta);
        assert!((fit / exact - 1.0).abs() < 0.002, "eta {eta}: fit {fit} against {exact}");
    }
    // Light from inside comes back out where it meets the interface within the critical
    // angle, ~1/η² of a diffuse flux: the rest is reflected back in (~0.6 at η = 1.49).
    assert!((0.55..0.65).contains(&internal), "internal reflectance {internal}");
    // At normal incidence nearly all gets through (1 − F = 0.961 for a smooth coating); at
    // grazing incidence the visible microfacets face the light more than the surface does,
    // so a rough coating still transmits some (0.37 here), but less.
    assert!(table[0] < 0.5 && (0.9..0.97).contains(&table[63]), "T(0) {} T(1) {}", table[0], table[63]);
}

/// An unlayered plastic (Mitsuba 3's `pplastic` in RGB) is its rough reflection plus the
/// base seen through two smooth refractions: f cos θ_i = F D G / (4 cos θ_o) +
/// ρ (1 − F(cos θ_o)) (1 − F(cos θ_i)) cos θ_i / π, with no 1/η² and no internal
/// reflections. The reflection is the layered plastic's (checked as the value at base 0);
/// the diffuse part against the closed form to 1e-12.
#[test]
fn an_unlayered_plastic_is_a_reflection_plus_a_doubly_refracted_base() {
    let base = [0.6f32, 0.3, 0.1];
    let mut rng = Rng(17);
    for i in 0..COATINGS.len() {
        let unlayered = mirror(plastic(i, base, COATING_UNLAYERED));
        let layered = mirror(plastic(i, base, 0));
        assert_eq!(unlayered.internal, 0.0);
        let black = |m: &MaterialF64| MaterialF64 { base_color: DVec3::ZERO, ..*m };
        for _ in 0..50 {
            let wo = direction(DVec3::Z, rng.range(0.02, 1.0), rng.range(0.0, 2.0 * PI));
            let wi = direction(DVec3::Z, rng.range(0.02, 1.0), rng.range(0.0, 2.0 * PI));
            let spec = bsdf::eval_local(&black(&unlayered), wo, wi);
            assert_eq!(spec, bsdf::eval_local(&black(&layered), wo, wi), "coating {i}: the reflection is the layered plastic's");
            let diffuse = bsdf::eval_local(&unlayered, wo, wi) - spec;
            let eta = unlayered.ior;
            let through = (1.0 - bsdf::dielectric_fresnel(wo.z, eta).0) * (1.0 - bsdf::dielectric_fresnel(wi.z, eta).0) * wi.z / PI;
            let expected = v3(base) * through;
            assert!((diffuse - expected).abs().max_element() <= 1e-12 * expected.max_element(), "coating {i}: {diffuse} against {expected}");
        }
    }
}
