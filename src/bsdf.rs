//! f64 mirror of glsl/lib/bsdf.glsl: the reference the GPU functions are tested against,
//! and the place where the model is checked for energy conservation, reciprocity and
//! correct derivatives (tests/suite/bsdf.rs).
//!
//! Invariant: every function here computes, step for step, what its GLSL namesake
//! computes, only in f64 (the same frame construction, the same lobe-selection rule, the
//! same sampling warps), so that a GPU result differs from the mirror by float32 rounding
//! alone. The model and its conventions are documented at the top of the GLSL file:
//! directions point away from the surface, the BSDF is one-sided, and [`eval`] returns
//! f(wo, wi) |cos theta_i|.

use crate::shared::{
    COATING_NONLINEAR, COATING_UNLAYERED, Material, MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_DIELECTRIC, MATERIAL_PLASTIC, MATERIAL_PLASTIC_BECKMANN, MATERIAL_PRINCIPLED,
    MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN, MATERIAL_THIN_DIELECTRIC, PLASTIC_TABLE_SIZE,
};
use glam::DVec3;
use std::f64::consts::PI;

/// Smallest GGX alpha (`BSDF_ALPHA_MIN`).
pub const ALPHA_MIN: f64 = 1e-3;
/// Rec. 709 luminance, used only for lobe selection (`BSDF_LUMINANCE`).
pub const LUMINANCE: DVec3 = DVec3::new(0.2126, 0.7152, 0.0722);

/// Entries of a plastic's transmittance table.
pub const TABLE: usize = PLASTIC_TABLE_SIZE as usize;

/// A plastic's transmittance table in f64. (A struct rather than a bare array field of
/// [`MaterialF64`]: rustc 1.95 fails (an internal error) on closures that capture part of a struct whose field
/// is an array with a named length and rebuild it with `..m`.)
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Table(pub [f64; TABLE]);

impl Default for Table {
    fn default() -> Self {
        Self([0.0; TABLE])
    }
}

/// Material parameters in f64, so that finite differences of the mirror are not limited
/// by the f32 storage of [`Material`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MaterialF64 {
    pub base_color: DVec3,
    pub roughness: f64,
    pub metallic: f64,
    pub kind: u32,
    /// A dielectric's relative index of refraction (the far side's over wo's).
    pub ior: f64,
    /// A conductor's complex index of refraction, eta + i k.
    pub eta: DVec3,
    pub k: DVec3,
    /// A plastic's coating: its transmittance table (the entries the kernel reads at
    /// `Material::table`), internal diffuse reflectance, `nonlinear` and whether it is
    /// unlayered (`COATING_UNLAYERED`: no 1/η², no internal reflections).
    pub transmittance: Table,
    pub internal: f64,
    pub nonlinear: bool,
    pub unlayered: bool,
    /// A plastic's specular tint.
    pub specular: DVec3,
}

impl From<Material> for MaterialF64 {
    /// Everything but a plastic's table, which [`Material`] only points to: see
    /// [`MaterialF64::with_tables`].
    fn from(m: Material) -> Self {
        Self {
            base_color: DVec3::new(m.base_color[0] as f64, m.base_color[1] as f64, m.base_color[2] as f64),
            roughness: m.roughness as f64,
            metallic: m.metallic as f64,
            kind: m.kind,
            ior: m.ior as f64,
            eta: DVec3::from(m.eta.map(f64::from)),
            k: DVec3::from(m.k.map(f64::from)),
            transmittance: Table::default(),
            internal: m.internal as f64,
            nonlinear: m.coating & COATING_NONLINEAR != 0,
            unlayered: m.coating & COATING_UNLAYERED != 0,
            specular: DVec3::from(m.specular.map(f64::from)),
        }
    }
}

impl MaterialF64 {
    /// `m` with a plastic's transmittance table read from `tables` at `m.table`, as the
    /// kernel reads it (`bsdf_table`).
    pub fn with_tables(m: Material, tables: &[f32]) -> Self {
        let mut out = Self::from(m);
        if out.plastic() {
            let start = m.table as usize;
            for (t, v) in out.transmittance.0.iter_mut().zip(&tables[start..start + TABLE]) {
                *t = f64::from(*v);
            }
        }
        out
    }
}

impl MaterialF64 {
    fn principled(&self) -> bool {
        self.kind == MATERIAL_PRINCIPLED
    }

    /// Glass of either kind (delta lobes).
    pub fn dielectric(&self) -> bool {
        self.kind == MATERIAL_DIELECTRIC || self.thin()
    }

    pub fn thin(&self) -> bool {
        self.kind == MATERIAL_THIN_DIELECTRIC
    }

    /// The rough dielectric of either distribution (lobes on both sides, no deltas).
    pub fn rough_glass(&self) -> bool {
        self.kind == MATERIAL_ROUGH_DIELECTRIC || self.kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN
    }

    /// The conductor of either distribution (one reflected lobe).
    pub fn conductor(&self) -> bool {
        self.kind == MATERIAL_CONDUCTOR || self.kind == MATERIAL_CONDUCTOR_BECKMANN
    }

    /// The plastic of either distribution (a glossy and a diffuse lobe).
    pub fn plastic(&self) -> bool {
        self.kind == MATERIAL_PLASTIC || self.kind == MATERIAL_PLASTIC_BECKMANN
    }

    /// The principled model's dielectric normal-incidence reflectance F0_d
    /// ([`principled_f0`] of its ior).
    fn f0_d(&self) -> f64 {
        principled_f0(self.ior)
    }

    /// mix(F0_d, base_color, metallic)
    fn f0(&self) -> DVec3 {
        DVec3::splat(self.f0_d()) * (1.0 - self.metallic) + self.base_color * self.metallic
    }
}

/// Orthonormal basis (t, b, n) of Duff et al. 2017, "Building an Orthonormal Basis,
/// Revisited" (`ShadingFrame`).
#[derive(Clone, Copy, Debug)]
pub struct ShadingFrame {
    pub t: DVec3,
    pub b: DVec3,
    pub n: DVec3,
}

impl ShadingFrame {
    pub fn new(n: DVec3) -> Self {
        let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
        let a = -1.0 / (s + n.z);
        let b = n.x * n.y * a;
        Self { t: DVec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x), b: DVec3::new(b, s + n.y * n.y * a, -n.y), n }
    }

    pub fn to_local(&self, v: DVec3) -> DVec3 {
        DVec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }

    pub fn to_world(&self, v: DVec3) -> DVec3 {
        v.x * self.t + v.y * self.b + v.z * self.n
    }
}

/// max(roughness^2, ALPHA_MIN)
pub fn alpha(roughness: f64) -> f64 {
    (roughness * roughness).max(ALPHA_MIN)
}

/// d alpha / d roughness (0 where the clamp holds).
pub fn dalpha_droughness(roughness: f64) -> f64 {
    if roughness * roughness > ALPHA_MIN {
        2.0 * roughness
    } else {
        0.0
    }
}

/// (1 - c)^5, Schlick's Fresnel weight.
pub fn schlick_weight(c: f64) -> f64 {
    let m = (1.0 - c).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

/// The principled model's dielectric normal-incidence reflectance from its index of
/// refraction, ((ior − 1)/(ior + 1))²: 0.04, glTF 2.0's dielectric, at ior 1.5
/// (`principled_f0`).
pub fn principled_f0(ior: f64) -> f64 {
    let r = (ior - 1.0) / (ior + 1.0);
    r * r
}

/// Schlick's Fresnel reflectance of normal-incidence reflectance `f0` at cosine `c`
/// (`bsdf_fresnel_schlick`).
pub fn fresnel_schlick(f0: f64, c: f64) -> f64 {
    f0 + (1.0 - f0) * schlick_weight(c)
}

/// `PrincipledTerms`: see the GLSL for what each term is and why it is written so.
struct PrincipledTerms {
    alpha: f64,
    h: DVec3,
    k: f64,
    s: f64,
    q_o: f64,
    q_i: f64,
    denom_o: f64,
    denom: f64,
    d: f64,
    specular: f64,
    diffuse: f64,
}

/// `principled_terms`; `h` is normalize(wo + wi), or the sampled microfacet normal.
fn principled_terms(m: &MaterialF64, wo: DVec3, wi: DVec3, h: DVec3) -> PrincipledTerms {
    let alpha = alpha(m.roughness);
    let f0_d = m.f0_d();
    let a2 = alpha * alpha;
    let k = a2 * h.z * h.z + h.x * h.x + h.y * h.y;
    let s = schlick_weight(wo.dot(h));
    let sin2_o = wo.x * wo.x + wo.y * wo.y;
    let sin2_i = wi.x * wi.x + wi.y * wi.y;
    let q_o = (wo.z * wo.z + a2 * sin2_o).sqrt();
    let q_i = (wi.z * wi.z + a2 * sin2_i).sqrt();
    let cos_lambda_o = a2 * sin2_o / (2.0 * (q_o + wo.z));
    let cos_o_lambda_i = (wo.z / wi.z) * a2 * sin2_i / (2.0 * (q_i + wi.z));
    let denom_o = wo.z + cos_lambda_o;
    let denom = denom_o + cos_o_lambda_i;
    let d = a2 / (PI * k * k);
    PrincipledTerms {
        alpha,
        h,
        k,
        s,
        q_o,
        q_i,
        denom_o,
        denom,
        d,
        specular: d / (4.0 * denom),
        diffuse: (1.0 - fresnel_schlick(f0_d, wo.z)) * (1.0 - fresnel_schlick(f0_d, wi.z)) * wi.z / PI,
    }
}

/// Probabilities that [`sample`] picks the (diffuse, specular) lobe
/// (`bsdf_lobe_probabilities`).
pub fn lobe_probabilities(m: &MaterialF64, cos_o: f64) -> [f64; 2] {
    if !m.principled() {
        return [1.0, 0.0];
    }
    let f0 = m.f0();
    let s = schlick_weight(cos_o);
    let spec = LUMINANCE.dot(f0 + (DVec3::ONE - f0) * s).max(0.0);
    let diff = ((1.0 - m.metallic) * LUMINANCE.dot(m.base_color) * (1.0 - fresnel_schlick(m.f0_d(), cos_o))).max(0.0);
    let total = spec + diff;
    if total > 0.0 {
        [diff / total, spec / total]
    } else {
        [0.0, 1.0]
    }
}

/// `principled_value`
fn principled_value(m: &MaterialF64, t: &PrincipledTerms) -> DVec3 {
    let f0 = m.f0();
    let fresnel = f0 + (DVec3::ONE - f0) * t.s;
    (1.0 - m.metallic) * t.diffuse * m.base_color + fresnel * t.specular
}

/// `principled_pdf`: cosine-weighted diffuse lobe, visible-normal specular lobe.
fn principled_pdf(p: [f64; 2], cos_i: f64, t: &PrincipledTerms) -> f64 {
    p[0] * (cos_i / PI) + p[1] * (t.d / (4.0 * t.denom_o))
}

/// The unpolarised Fresnel reflectance at cos_i > 0 of an interface of relative index eta,
/// and the refracted cosine (0 under total internal reflection, where it returns 1)
/// (`dielectric_fresnel`).
pub fn dielectric_fresnel(cos_i: f64, eta: f64) -> (f64, f64) {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    (0.5 * (rs * rs + rp * rp), cos_t)
}

/// `MicrofacetTerms`: see the GLSL for the model and what each term is.
#[derive(Clone, Copy, Debug)]
struct MicrofacetTerms {
    valid: bool,
    dln_d: f64,
    dln_g1: f64,
    value: f64,
    density: f64,
    oh: f64,
    fresnel: f64,
    reflect: bool,
}

/// Smith's G1 of GGX and d ln G1 / d alpha (`ggx_g1`).
fn ggx_g1(v: DVec3, alpha: f64) -> (f64, f64) {
    let a2 = alpha * alpha;
    let c = v.z.abs();
    let s2 = v.x * v.x + v.y * v.y;
    let q = (c * c + a2 * s2).sqrt();
    let lambda = a2 * s2 / (2.0 * c * (q + c));
    (1.0 / (1.0 + lambda), -(alpha * s2 / (2.0 * c * q)) / (1.0 + lambda))
}

/// Smith's G1 of Beckmann (Walter et al.'s rational approximation) and d ln G1 / d alpha
/// (`beckmann_g1`).
fn beckmann_g1(v: DVec3, alpha: f64) -> (f64, f64) {
    let c = v.z.abs();
    let s = (v.x * v.x + v.y * v.y).sqrt();
    if c >= 1.6 * alpha * s {
        return (1.0, 0.0);
    }
    let a = c / (alpha * s);
    let num = (3.535 + 2.181 * a) * a;
    let den = 1.0 + (2.276 + 2.577 * a) * a;
    let dnum = 3.535 + 4.362 * a;
    let dden = 2.276 + 5.154 * a;
    (num / den, (dden / den - dnum / num) * a / alpha)
}

/// 1 + erf(x) from Abramowitz and Stegun's 7.1.26 (`bsdf_one_plus_erf`).
pub fn one_plus_erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.3275911 * x.abs());
    let q = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))) * (-x * x).exp();
    if x < 0.0 {
        q
    } else {
        2.0 - q
    }
}

/// The inverse of erf at x given (1 − x)(1 + x), Giles 2010's single-precision
/// polynomials (`bsdf_erfinv`).
pub fn erfinv(x: f64, one_minus_x2: f64) -> f64 {
    let mut w = -one_minus_x2.ln();
    let p = if w < 5.0 {
        w -= 2.5;
        [3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087, -0.00125372503, -0.00417768164, 0.246640727, 1.50140941]
            .iter()
            .fold(2.81022636e-08, |p, c| c + p * w)
    } else {
        w = w.sqrt() - 3.0;
        [0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773, -0.0076224613, 0.00943887047, 1.00167406, 2.83297682]
            .iter()
            .fold(-0.000200214257, |p, c| c + p * w)
    };
    p * x
}

/// 1 / √π (`BSDF_INV_SQRT_PI`).
const INV_SQRT_PI: f64 = 0.564_189_583_547_756_3;

/// A Beckmann normal from the visible normals seen from wo (`beckmann_sample_visible_normal`).
pub fn beckmann_sample_visible_normal(wo: DVec3, alpha: f64, u: [f64; 2]) -> DVec3 {
    let v = DVec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let sin_o = (v.x * v.x + v.y * v.y).sqrt();
    let tan_o = sin_o / v.z;
    let cot_o = if sin_o > 0.0 { v.z / sin_o } else { 1e15 };
    let ux = u[0].max(1e-6);
    let e_cot = one_plus_erf(cot_o);
    let norm = 1.0 / (e_cot + INV_SQRT_PI * tan_o * (-cot_o * cot_o).exp());
    let theta = sin_o.atan2(v.z);
    let fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta));
    let c = e_cot - 1.0;
    let b = c - (1.0 + c) * (1.0 - ux).powf(fit);
    let (mut lo, mut hi) = (-6.0, cot_o.min(6.0));
    let mut x = erfinv(b, (1.0 - b) * (1.0 + b));
    for _ in 0..10 {
        if !(x >= lo && x <= hi) {
            x = 0.5 * (lo + hi);
        }
        let g = (-x * x).exp();
        let value = norm * (one_plus_erf(x) + INV_SQRT_PI * tan_o * g) - ux;
        let density = norm * (2.0 * INV_SQRT_PI) * g * (1.0 - x * tan_o);
        if value > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        x -= value / density;
    }
    if !(x >= lo && x <= hi) {
        x = 0.5 * (lo + hi);
    }
    let uy = u[1].clamp(1e-6, 1.0 - 1e-6);
    let (sx, sy) = (x, erfinv(2.0 * uy - 1.0, 4.0 * uy * (1.0 - uy)));
    let (cos_phi, sin_phi) = if sin_o > 0.0 { (v.x / sin_o, v.y / sin_o) } else { (1.0, 0.0) };
    let (px, py) = (alpha * (cos_phi * sx - sin_phi * sy), alpha * (sin_phi * sx + cos_phi * sy));
    DVec3::new(-px, -py, 1.0).normalize()
}

/// Smith's exact G1 of Beckmann (`beckmann_g1_exact`).
fn beckmann_g1_exact(v: DVec3, alpha: f64) -> f64 {
    let c = v.z.abs();
    let s = (v.x * v.x + v.y * v.y).sqrt();
    if s.is_nan() || s <= 0.0 {
        return 1.0;
    }
    let a = c / (alpha * s);
    2.0 / (one_plus_erf(a) + INV_SQRT_PI * (-a * a).exp() / a)
}

/// `microfacet_terms`
fn microfacet_terms(roughness: f64, beckmann: bool, eta: f64, wo: DVec3, wi: DVec3, h: DVec3) -> MicrofacetTerms {
    let reflect = wi.z > 0.0;
    let a = alpha(roughness);
    let a2 = a * a;
    let (oh, ih) = (wo.dot(h), wi.dot(h));
    let mut valid = wo.z > 0.0 && wi.z != 0.0 && oh > 0.0 && if reflect { ih > 0.0 } else { ih < 0.0 };
    let (d, dln_d, (g1_o, dln_o), (g1_i, dln_i)) = if beckmann {
        let t2 = (h.x * h.x + h.y * h.y) / (h.z * h.z);
        let c2 = h.z * h.z;
        ((-t2 / a2).exp() / (PI * a2 * c2 * c2), 2.0 * t2 / (a2 * a) - 2.0 / a, beckmann_g1(wo, a), beckmann_g1(wi, a))
    } else {
        let k = a2 * h.z * h.z + h.x * h.x + h.y * h.y;
        (a2 / (PI * k * k), 2.0 / a - 4.0 * a * h.z * h.z / k, ggx_g1(wo, a), ggx_g1(wi, a))
    };
    let jac = if reflect {
        1.0 / (4.0 * oh)
    } else {
        let den = oh + eta * ih;
        eta * eta * ih.abs() / (den * den)
    };
    let visible = d * g1_o * oh * jac / wo.z;
    let mut value = visible * g1_i;
    let mut density = if beckmann { visible * (beckmann_g1_exact(wo, a) / g1_o) } else { visible };
    if !valid || density.is_nan() || density <= 0.0 {
        valid = false;
        value = 0.0;
        density = 0.0;
    }
    MicrofacetTerms { valid, dln_d, dln_g1: dln_o + dln_i, value, density, oh, fresnel: 0.0, reflect }
}

/// `rough_glass_terms`
fn rough_glass_terms(m: &MaterialF64, wo: DVec3, wi: DVec3, h: DVec3) -> MicrofacetTerms {
    let mut t = microfacet_terms(m.roughness, m.kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN, m.ior, wo, wi, h);
    t.fresnel = dielectric_fresnel(t.oh, m.ior).0;
    t
}

/// `rough_glass_half`
fn rough_glass_half(m: &MaterialF64, wo: DVec3, wi: DVec3) -> DVec3 {
    let h = if wi.z > 0.0 { wo + wi } else { wo + m.ior * wi }.normalize();
    if h.z < 0.0 {
        -h
    } else {
        h
    }
}

/// `rough_glass_tint`
fn rough_glass_tint(m: &MaterialF64, t: &MicrofacetTerms) -> DVec3 {
    if t.reflect {
        DVec3::ONE
    } else {
        m.base_color / (m.ior * m.ior)
    }
}

/// `rough_glass_value`
fn rough_glass_value(m: &MaterialF64, t: &MicrofacetTerms) -> DVec3 {
    if !t.valid {
        return DVec3::ZERO;
    }
    let prob = if t.reflect { t.fresnel } else { 1.0 - t.fresnel };
    (prob * t.value) * rough_glass_tint(m, t)
}

/// `rough_glass_pdf`
fn rough_glass_pdf(t: &MicrofacetTerms) -> f64 {
    if !t.valid {
        return 0.0;
    }
    (if t.reflect { t.fresnel } else { 1.0 - t.fresnel }) * t.density
}

/// The unpolarised Fresnel reflectance of a conductor of complex index eta + i k at cos_i
/// (`conductor_fresnel`).
pub fn conductor_fresnel(c: f64, eta: DVec3, k: DVec3) -> DVec3 {
    let c2 = c * c;
    let s2 = 1.0 - c2;
    let t0 = eta * eta - k * k - DVec3::splat(s2);
    let sqrt = |v: DVec3| DVec3::new(v.x.sqrt(), v.y.sqrt(), v.z.sqrt());
    let a2b2 = sqrt(t0 * t0 + 4.0 * eta * eta * k * k);
    let a = sqrt((0.5 * (a2b2 + t0)).max(DVec3::ZERO));
    let t1 = a2b2 + DVec3::splat(c2);
    let t2 = 2.0 * c * a;
    let rs = (t1 - t2) / (t1 + t2);
    let t3 = c2 * a2b2 + DVec3::splat(s2 * s2);
    let t4 = t2 * s2;
    let rp = rs * (t3 - t4) / (t3 + t4);
    0.5 * (rs + rp)
}

/// `conductor_terms`
fn conductor_terms(m: &MaterialF64, wo: DVec3, wi: DVec3, h: DVec3) -> MicrofacetTerms {
    microfacet_terms(m.roughness, m.kind == MATERIAL_CONDUCTOR_BECKMANN, 1.0, wo, wi, h)
}

/// `conductor_value`
fn conductor_value(m: &MaterialF64, t: &MicrofacetTerms) -> DVec3 {
    if !t.valid {
        return DVec3::ZERO;
    }
    t.value * conductor_fresnel(t.oh, m.eta, m.k) * m.base_color
}

/// `plastic_transmittance`
fn plastic_transmittance(m: &MaterialF64, c: f64) -> f64 {
    if m.unlayered {
        return 1.0 - dielectric_fresnel(c, m.ior).0;
    }
    let x = c * (TABLE - 1) as f64;
    let i = (x as i64).min(TABLE as i64 - 2) as usize;
    let w = x - i as f64;
    m.transmittance.0[i] * (1.0 - w) + m.transmittance.0[i + 1] * w
}

/// `plastic_terms`
fn plastic_terms(m: &MaterialF64, wo: DVec3, wi: DVec3, h: DVec3) -> MicrofacetTerms {
    microfacet_terms(m.roughness, m.kind == MATERIAL_PLASTIC_BECKMANN, 1.0, wo, wi, h)
}

/// `plastic_diffuse`
fn plastic_diffuse(m: &MaterialF64, wo: DVec3, wi: DVec3) -> f64 {
    let spread = if m.unlayered { 1.0 } else { m.ior * m.ior };
    wi.z * plastic_transmittance(m, wo.z) * plastic_transmittance(m, wi.z) / (PI * spread)
}

/// 1 − the internal reflectance's share (`plastic_base`'s denominator).
fn plastic_kept(m: &MaterialF64) -> DVec3 {
    DVec3::ONE - if m.nonlinear { m.base_color * m.internal } else { DVec3::splat(m.internal) }
}

/// `plastic_value`
fn plastic_value(m: &MaterialF64, wo: DVec3, wi: DVec3, t: &MicrofacetTerms) -> DVec3 {
    let spec = if t.valid { t.value * dielectric_fresnel(t.oh, m.ior).0 } else { 0.0 };
    m.specular * spec + m.base_color / plastic_kept(m) * plastic_diffuse(m, wo, wi)
}

/// `plastic_specular_prob`
fn plastic_specular_prob(m: &MaterialF64, cos_o: f64) -> f64 {
    let t = plastic_transmittance(m, cos_o);
    let s = ((m.specular.x + m.specular.y + m.specular.z) / 3.0).max(0.0);
    let d = ((m.base_color.x + m.base_color.y + m.base_color.z) / 3.0).max(0.0);
    let w = if s + d > 0.0 { s / (s + d) } else { 0.5 };
    let spec = (1.0 - t) * w;
    let total = spec + t * (1.0 - w);
    if total > 0.0 {
        spec / total
    } else {
        1.0
    }
}

/// `plastic_pdf`
fn plastic_pdf(prob: f64, wi: DVec3, t: &MicrofacetTerms) -> f64 {
    prob * if t.valid { t.density } else { 0.0 } + (1.0 - prob) * wi.z / PI
}

/// The Gauss–Legendre rule of `n` points on [−1, 1]: (node, weight) pairs, the nodes by
/// Newton's method on the Legendre polynomial P_n from Chebyshev-like starting points.
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let k = k as f64;
                    let p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
                    (p0, p1) = (p1, p2);
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// The albedo of an interface of relative index `eta` on microfacets of `alpha`
/// (Beckmann's or GGX's) for light from the direction at cosine `mu` (on the side its
/// normal points to): what it transmits once (`transmit`) or reflects once, as Mitsuba 3
/// integrates it for its plastics: each visible normal's Fresnel term (1 − F or F) times
/// Smith's masking of the direction the light leaves in, integrated over the visible
/// normals by a product Gauss–Legendre rule in the sampler's two numbers (32 points each
/// way for η > 1, 128 otherwise, where total internal reflection makes the integrand
/// jump).
pub fn coating_albedo(beckmann: bool, alpha: f64, eta: f64, mu: f64, transmit: bool) -> f64 {
    albedo_by_rule(&coating_rule(eta), beckmann, alpha, eta, mu, transmit)
}

/// The Gauss–Legendre rule [`coating_albedo`] uses for an interface of index `eta`.
fn coating_rule(eta: f64) -> Vec<(f64, f64)> {
    gauss_legendre(if eta > 1.0 { 32 } else { 128 })
}

/// [`coating_albedo`] with the rule given, so that a table computes it once.
fn albedo_by_rule(rule: &[(f64, f64)], beckmann: bool, alpha: f64, eta: f64, mu: f64, transmit: bool) -> f64 {
    let g1 = |v: DVec3, m: DVec3| {
        if v.dot(m) * v.z <= 0.0 {
            0.0
        } else if beckmann {
            beckmann_g1(v, alpha).0
        } else {
            ggx_g1(v, alpha).0
        }
    };
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut sum = 0.0;
    for &(x, wx) in rule {
        for &(y, wy) in rule {
            let m = sample_visible_normal(beckmann, wi, alpha, DVec3::new(0.0, 0.5 * x + 0.5, 0.5 * y + 0.5));
            let c = wi.dot(m);
            let (f, cos_t) = dielectric_fresnel(c, eta);
            let g = if transmit {
                let wt = (c / eta - cos_t) * m - wi / eta;
                if f < 1.0 && wt.z < 0.0 {
                    g1(wt, m) * (1.0 - f)
                } else {
                    0.0
                }
            } else {
                let wr = 2.0 * c * m - wi;
                if wr.z > 0.0 {
                    g1(wr, m) * f
                } else {
                    0.0
                }
            };
            sum += g * wx * wy * 0.25;
        }
    }
    sum
}

/// A plastic's coating as Mitsuba 3 tabulates it, for a coating of relative index `eta`
/// (interior over exterior) on microfacets of `roughness` (Beckmann's or GGX's; alpha =
/// [`alpha`]`(roughness)`): the directional transmittance T(μ) at μ = max(10⁻⁶,
/// i / (TABLE − 1)) and the internal diffuse reflectance. A rough coating's are its
/// `roughplastic`'s: T(μ) the [`coating_albedo`] of the transmission, the internal
/// reflectance 2 · mean_i R(μ_i, 1/η) μ_i over the same μ (Mitsuba's sum), R the albedo of
/// the reflection from inside. A coating at the smallest alpha ([`ALPHA_MIN`]) is its
/// smooth `plastic`'s: T(μ) = 1 − F(μ) and the internal reflectance of
/// [`fresnel_diffuse_reflectance`].
pub fn coating(beckmann: bool, roughness: f64, eta: f64) -> ([f64; TABLE], f64) {
    let mu = |i: usize| (i as f64 / (TABLE - 1) as f64).max(1e-6);
    if roughness * roughness <= ALPHA_MIN {
        return (std::array::from_fn(|i| 1.0 - dielectric_fresnel(mu(i), eta).0), fresnel_diffuse_reflectance(1.0 / eta));
    }
    let a = alpha(roughness);
    let (outside, inside) = (coating_rule(eta), coating_rule(1.0 / eta));
    let transmittance = std::array::from_fn(|i| albedo_by_rule(&outside, beckmann, a, eta, mu(i), true));
    let internal = 2.0 * (0..TABLE).map(|i| albedo_by_rule(&inside, beckmann, a, 1.0 / eta, mu(i), false) * mu(i)).sum::<f64>() / TABLE as f64;
    (transmittance, internal)
}

/// The diffuse Fresnel reflectance of an interface of relative index `eta` (the fraction
/// of a uniform diffuse flux it reflects) by the fits Mitsuba 3 uses: Egan and Hilgeman's
/// (1973) below 1, d'Eon and Irving's (2011) above.
pub fn fresnel_diffuse_reflectance(eta: f64) -> f64 {
    if eta < 1.0 {
        0.0636 / eta + eta * (eta * -1.4399 + 0.7099) + 0.6681
    } else {
        [0.919317, -3.4793, 6.75335, -7.80989, 4.98554, -1.36881].iter().rev().fold(0.0, |acc, c| acc / eta + c)
    }
}

/// f cos theta_i in the local frame (`bsdf_eval_local`).
pub fn eval_local(m: &MaterialF64, wo: DVec3, wi: DVec3) -> DVec3 {
    if m.rough_glass() {
        return rough_glass_value(m, &rough_glass_terms(m, wo, wi, rough_glass_half(m, wo, wi)));
    }
    if wo.z <= 0.0 || wi.z <= 0.0 || m.dielectric() {
        return DVec3::ZERO;
    }
    if m.conductor() {
        return conductor_value(m, &conductor_terms(m, wo, wi, (wo + wi).normalize()));
    }
    if m.plastic() {
        return plastic_value(m, wo, wi, &plastic_terms(m, wo, wi, (wo + wi).normalize()));
    }
    if !m.principled() {
        return m.base_color * (wi.z / PI);
    }
    principled_value(m, &principled_terms(m, wo, wi, (wo + wi).normalize()))
}

/// Mixture pdf in the local frame (`bsdf_pdf_local`).
pub fn pdf_local(m: &MaterialF64, wo: DVec3, wi: DVec3) -> f64 {
    if m.rough_glass() {
        return rough_glass_pdf(&rough_glass_terms(m, wo, wi, rough_glass_half(m, wo, wi)));
    }
    if wo.z <= 0.0 || wi.z <= 0.0 || m.dielectric() {
        return 0.0;
    }
    if m.conductor() {
        return conductor_terms(m, wo, wi, (wo + wi).normalize()).density;
    }
    if m.plastic() {
        return plastic_pdf(plastic_specular_prob(m, wo.z), wi, &plastic_terms(m, wo, wi, (wo + wi).normalize()));
    }
    if !m.principled() {
        return wi.z / PI;
    }
    let p = lobe_probabilities(m, wo.z);
    principled_pdf(p, wi.z, &principled_terms(m, wo, wi, (wo + wi).normalize()))
}

/// Malley's method with the polar disk mapping (`bsdf_sample_cosine_hemisphere`).
pub fn sample_cosine_hemisphere(u: [f64; 2]) -> DVec3 {
    let r = u[0].sqrt();
    let phi = 2.0 * PI * u[1];
    DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u[0]).max(0.0).sqrt())
}

/// GGX visible-normal sample, Heitz 2018 listing 1 (`ggx_sample_visible_normal`).
pub fn ggx_sample_visible_normal(wo: DVec3, alpha: f64, u: [f64; 2]) -> DVec3 {
    let vh = DVec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 0.0 { DVec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt() } else { DVec3::X };
    let t2 = vh.cross(t1);
    let r = u[0].sqrt();
    let phi = 2.0 * PI * u[1];
    let p1 = r * phi.cos();
    let mut p2 = r * phi.sin();
    let s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    DVec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

/// f(wo, wi) |cos theta_i| (`bsdf_eval`).
pub fn eval(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> DVec3 {
    let f = ShadingFrame::new(n);
    eval_local(m, f.to_local(wo), f.to_local(wi))
}

/// Solid-angle pdf of [`sample`] (`bsdf_pdf`).
pub fn pdf(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> f64 {
    let f = ShadingFrame::new(n);
    pdf_local(m, f.to_local(wo), f.to_local(wi))
}

/// A direction drawn by [`sample`].
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: DVec3,
    /// eval / pdf
    pub weight: DVec3,
    pub pdf: f64,
}

/// A visible normal of either distribution from u.yz (the ternary of `bsdf_sample`'s rough
/// glass and conductor branches).
fn sample_visible_normal(beckmann: bool, wo: DVec3, alpha: f64, u: DVec3) -> DVec3 {
    if beckmann {
        beckmann_sample_visible_normal(wo, alpha, [u.y, u.z])
    } else {
        ggx_sample_visible_normal(wo, alpha, [u.y, u.z])
    }
}

/// wi and its microfacet normal for a glossy and a diffuse lobe (`bsdf_sample_two_lobes`):
/// with probability `prob` (u.x < prob) the mirror of wo about a visible normal of either
/// distribution, else a cosine-weighted direction with the normal halfway.
fn sample_two_lobes(prob: f64, beckmann: bool, wo: DVec3, alpha: f64, u: DVec3) -> (DVec3, DVec3) {
    if u.x < prob {
        let h = sample_visible_normal(beckmann, wo, alpha, u);
        (2.0 * wo.dot(h) * h - wo, h)
    } else {
        let wi = sample_cosine_hemisphere([u.y, u.z]);
        (wi, (wo + wi).normalize())
    }
}

/// `bsdf_sample`: `None` where the GLSL returns false.
pub fn sample(m: &MaterialF64, n: DVec3, wo: DVec3, u: DVec3) -> Option<BsdfSample> {
    let f = ShadingFrame::new(n);
    let wo_l = f.to_local(wo);
    if wo_l.z <= 0.0 || m.dielectric() {
        return None;
    }
    if m.rough_glass() {
        let h = sample_visible_normal(m.kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN, wo_l, alpha(m.roughness), u);
        let oh = wo_l.dot(h);
        let (fr, cos_t) = dielectric_fresnel(oh, m.ior);
        let wi_l = if u.x < fr { 2.0 * oh * h - wo_l } else { ((oh * h - wo_l) / m.ior - cos_t * h).normalize() };
        let t = rough_glass_terms(m, wo_l, wi_l, h);
        let pdf = rough_glass_pdf(&t);
        if pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        return Some(BsdfSample { wi: f.to_world(wi_l), weight: rough_glass_value(m, &t) / pdf, pdf });
    }
    if m.conductor() {
        let h = sample_visible_normal(m.kind == MATERIAL_CONDUCTOR_BECKMANN, wo_l, alpha(m.roughness), u);
        let wi_l = 2.0 * wo_l.dot(h) * h - wo_l;
        if wi_l.z <= 0.0 {
            return None;
        }
        let t = conductor_terms(m, wo_l, wi_l, h);
        if t.density.is_nan() || t.density <= 0.0 {
            return None;
        }
        return Some(BsdfSample { wi: f.to_world(wi_l), weight: conductor_value(m, &t) / t.density, pdf: t.density });
    }
    if m.plastic() {
        let prob = plastic_specular_prob(m, wo_l.z);
        let (wi_l, h) = sample_two_lobes(prob, m.kind == MATERIAL_PLASTIC_BECKMANN, wo_l, alpha(m.roughness), u);
        if wi_l.z <= 0.0 {
            return None;
        }
        let t = plastic_terms(m, wo_l, wi_l, h);
        let pdf = plastic_pdf(prob, wi_l, &t);
        if pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        return Some(BsdfSample { wi: f.to_world(wi_l), weight: plastic_value(m, wo_l, wi_l, &t) / pdf, pdf });
    }
    if !m.principled() {
        let wi_l = sample_cosine_hemisphere([u.y, u.z]);
        if wi_l.z <= 0.0 {
            return None;
        }
        return Some(BsdfSample { wi: f.to_world(wi_l), weight: m.base_color, pdf: wi_l.z / PI });
    }
    let p = lobe_probabilities(m, wo_l.z);
    let (wi_l, h) = sample_two_lobes(p[1], false, wo_l, alpha(m.roughness), u);
    if wi_l.z <= 0.0 {
        return None;
    }
    let t = principled_terms(m, wo_l, wi_l, h);
    let pdf = principled_pdf(p, wi_l.z, &t);
    // A zero or NaN pdf (possible only through extreme inputs) yields no sample.
    if pdf.is_nan() || pdf <= 0.0 {
        return None;
    }
    Some(BsdfSample { wi: f.to_world(wi_l), weight: principled_value(m, &t) / pdf, pdf })
}

/// Derivatives of [`eval`]'s value per colour channel (`bsdf_eval_grad`): `d_base_color[c]`
/// = dv_c/dbase_color_c (the Jacobian is diagonal), `d_roughness[c]` = dv_c/droughness,
/// `d_metallic[c]` = dv_c/dmetallic.
#[derive(Clone, Copy, Debug, Default)]
pub struct EvalGrad {
    pub d_base_color: DVec3,
    pub d_roughness: DVec3,
    pub d_metallic: DVec3,
}

/// `bsdf_eval_grad`; the formulas are derived in the GLSL comment.
pub fn eval_grad(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> EvalGrad {
    let mut g = EvalGrad::default();
    let f = ShadingFrame::new(n);
    let wo_l = f.to_local(wo);
    let wi_l = f.to_local(wi);
    if m.rough_glass() {
        let t = rough_glass_terms(m, wo_l, wi_l, rough_glass_half(m, wo_l, wi_l));
        if t.valid && !t.reflect {
            g.d_base_color = DVec3::splat((1.0 - t.fresnel) * t.value / (m.ior * m.ior));
        }
        let dalpha = dalpha_droughness(m.roughness);
        if t.valid && dalpha != 0.0 {
            g.d_roughness = rough_glass_value(m, &t) * ((t.dln_d + t.dln_g1) * dalpha);
        }
        return g;
    }
    if wo_l.z <= 0.0 || wi_l.z <= 0.0 || m.dielectric() {
        return g;
    }
    if m.conductor() {
        let t = conductor_terms(m, wo_l, wi_l, (wo_l + wi_l).normalize());
        if !t.valid {
            return g;
        }
        g.d_base_color = t.value * conductor_fresnel(t.oh, m.eta, m.k);
        let dalpha = dalpha_droughness(m.roughness);
        if dalpha != 0.0 {
            g.d_roughness = conductor_value(m, &t) * ((t.dln_d + t.dln_g1) * dalpha);
        }
        return g;
    }
    if m.plastic() {
        let kept = plastic_kept(m);
        g.d_base_color = plastic_diffuse(m, wo_l, wi_l) / if m.nonlinear { kept * kept } else { kept };
        return g;
    }
    if !m.principled() {
        g.d_base_color = DVec3::splat(wi_l.z / PI);
        return g;
    }
    let t = principled_terms(m, wo_l, wi_l, (wo_l + wi_l).normalize());
    let f0 = m.f0();
    let fresnel = f0 + (DVec3::ONE - f0) * t.s;
    g.d_base_color = DVec3::splat((1.0 - m.metallic) * t.diffuse + m.metallic * (1.0 - t.s) * t.specular);
    g.d_metallic = -m.base_color * t.diffuse + (m.base_color - DVec3::splat(m.f0_d())) * ((1.0 - t.s) * t.specular);
    let dalpha = dalpha_droughness(m.roughness);
    if dalpha != 0.0 {
        let a = t.alpha;
        let dln_d = 2.0 / a - 4.0 * a * t.h.z * t.h.z / t.k;
        let sin2_o = wo_l.x * wo_l.x + wo_l.y * wo_l.y;
        let sin2_i = wi_l.x * wi_l.x + wi_l.y * wi_l.y;
        let ddenom = a * sin2_o / (2.0 * t.q_o) + (wo_l.z / wi_l.z) * a * sin2_i / (2.0 * t.q_i);
        g.d_roughness = fresnel * (t.specular * (dln_d - ddenom / t.denom) * dalpha);
    }
    g
}

/// R: the Fresnel reflectance, or a thin sheet's 2F / (1 + F); and the refracted cosine
/// (`dielectric_reflectance`).
pub fn dielectric_reflectance(m: &MaterialF64, cos_i: f64) -> (f64, f64) {
    let (fr, cos_t) = dielectric_fresnel(cos_i, m.ior);
    (if m.thin() { 2.0 * fr / (1.0 + fr) } else { fr }, cos_t)
}

/// The transmitted lobe's radiance factor per unit (1 − R) and unit base colour: 1/η², or 1
/// through a thin sheet (`dielectric_crossing`).
pub fn dielectric_crossing(m: &MaterialF64) -> f64 {
    if m.thin() {
        1.0
    } else {
        1.0 / (m.ior * m.ior)
    }
}

/// The probability of wi's lobe: R above the surface, 1 − R below (`dielectric_prob`).
pub fn dielectric_prob(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> f64 {
    let cos_i = wo.dot(n);
    if cos_i <= 0.0 {
        return 0.0;
    }
    let (r, _) = dielectric_reflectance(m, cos_i);
    if wi.dot(n) > 0.0 {
        r
    } else {
        1.0 - r
    }
}

/// The lobe's mass at wi: R, or (1 − R) [`dielectric_crossing`] base_color (`dielectric_mass`).
pub fn dielectric_mass(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> DVec3 {
    let cos_i = wo.dot(n);
    if cos_i <= 0.0 {
        return DVec3::ZERO;
    }
    let (r, _) = dielectric_reflectance(m, cos_i);
    if wi.dot(n) > 0.0 {
        DVec3::splat(r)
    } else {
        (1.0 - r) * dielectric_crossing(m) * m.base_color
    }
}

/// d [`dielectric_mass`] / d base_color per channel (`dielectric_mass_grad`).
pub fn dielectric_mass_grad(m: &MaterialF64, n: DVec3, wo: DVec3, wi: DVec3) -> DVec3 {
    let cos_i = wo.dot(n);
    if cos_i <= 0.0 || wi.dot(n) > 0.0 {
        return DVec3::ZERO;
    }
    let (r, _) = dielectric_reflectance(m, cos_i);
    DVec3::splat((1.0 - r) * dielectric_crossing(m))
}

/// `dielectric_sample`: the mirror when u < R, else the transmission (refracted, or
/// straight through a thin sheet); `pdf` is the lobe's probability and `weight` its mass
/// over it. `None` where the GLSL returns false.
pub fn dielectric_sample(m: &MaterialF64, n: DVec3, wo: DVec3, u: f64) -> Option<BsdfSample> {
    let cos_i = wo.dot(n);
    if cos_i <= 0.0 {
        return None;
    }
    let (r, cos_t) = dielectric_reflectance(m, cos_i);
    let s = if u < r {
        BsdfSample { wi: 2.0 * cos_i * n - wo, weight: DVec3::ONE, pdf: r }
    } else {
        let wi = if m.thin() { -wo } else { ((cos_i * n - wo) / m.ior - cos_t * n).normalize() };
        BsdfSample { wi, weight: dielectric_crossing(m) * m.base_color, pdf: 1.0 - r }
    };
    (s.pdf > 0.0).then_some(s)
}
