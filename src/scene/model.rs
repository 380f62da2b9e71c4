//! The scene model: what every loader (TOML, glTF, Mitsuba XML) produces and the renderer,
//! optimiser and writers consume. Nothing here reads a file.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use super::file::MaterialType as MaterialKind;
use crate::image::Image;

/// Largest film and texture side accepted; larger values are typos, not scenes.
pub const MAX_IMAGE_SIDE: u32 = crate::image::MAX_IMAGE_SIDE;

/// Most triangles a scene may hold: refused as a file is read, before its memory is spent
/// (a device holds fewer still: its buffer limits are checked when the scene is uploaded).
pub const MAX_TRIANGLES: usize = 1 << 24;

/// Refuses `more` triangles on top of `meshes`' beyond [`MAX_TRIANGLES`].
pub(crate) fn check_triangles(meshes: &[Mesh], more: usize) -> Result<(), String> {
    let total = meshes.iter().map(|m| m.indices.len()).sum::<usize>() + more;
    if total > MAX_TRIANGLES {
        return Err(format!("{total} triangles, more than the {MAX_TRIANGLES} a scene may hold"));
    }
    Ok(())
}

/// Largest magnitude of a vertex coordinate: far beyond any scene's, and well inside what
/// the BVH build handles (it fails near 1e19).
pub const MAX_COORDINATE: f32 = 1e12;
/// The widest pixel filter, in pixels from the centre (a Gaussian's 4σ, a tent's radius).
pub const MAX_FILTER_RADIUS: f32 = 16.0;
/// Deepest path accepted; beyond this the GPU's per-path replay state is wasted.
pub const MAX_DEPTH: u32 = 1024;
/// A dielectric's index of refraction (interior over exterior) when none is given: glass
/// in air.
pub const DEFAULT_IOR: f32 = 1.5;
/// The range of relative indices of refraction a dielectric may have (below 1: a less
/// dense interior, such as a bubble in water).
pub const MIN_IOR: f32 = 0.25;
pub const MAX_IOR: f32 = 4.0;
/// A rough dielectric's or a conductor's roughness when the scene gives none (alpha 0.09,
/// near Mitsuba's default alpha of 0.1).
pub const DEFAULT_MICROFACET_ROUGHNESS: f32 = 0.3;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Film {
    pub width: u32,
    pub height: u32,
}

/// How a pixel weighs the points of the image plane around its centre (`[film] filter`,
/// Mitsuba's `rfilter`), separably in x and y. The kernels draw each camera sample's
/// offset from the pixel's centre in proportion to the weight (filter importance
/// sampling), so that a pixel's mean is the filter-weighted mean of the image plane, as
/// a renderer that splats samples onto their neighbours with these weights converges to.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum PixelFilter {
    /// Uniform over the pixel (the default).
    #[default]
    Box,
    /// Mitsuba's `gaussian`: exp(−x²/2σ²) less its value at the radius 4σ, in pixels.
    Gaussian { stddev: f32 },
    /// Mitsuba's `tent`: 1 − |x|/radius, in pixels.
    Tent { radius: f32 },
}

impl PixelFilter {
    /// A Gaussian of standard deviation `stddev` pixels (0.5, Mitsuba's, where None), in
    /// (0, [`MAX_FILTER_RADIUS`] / 4]; Err: the value and the range it is not in.
    pub fn gaussian(stddev: Option<f32>) -> Result<Self, String> {
        Ok(Self::Gaussian { stddev: filter_size(stddev, 0.5, MAX_FILTER_RADIUS / 4.0)? })
    }

    /// A tent of radius `radius` pixels (1 where None), in (0, [`MAX_FILTER_RADIUS`]];
    /// Err: the value and the range it is not in.
    pub fn tent(radius: Option<f32>) -> Result<Self, String> {
        Ok(Self::Tent { radius: filter_size(radius, 1.0, MAX_FILTER_RADIUS)? })
    }

    /// The widest offset from the pixel's centre, in pixels.
    pub fn radius(self) -> f32 {
        match self {
            PixelFilter::Box => 0.5,
            PixelFilter::Gaussian { stddev } => 4.0 * stddev,
            PixelFilter::Tent { radius } => radius,
        }
    }

    /// The weight at offset x (in pixels) along one axis, unnormalised.
    pub fn weight(self, x: f64) -> f64 {
        let r = f64::from(self.radius());
        match self {
            _ if x.abs() > r => 0.0,
            PixelFilter::Box => 1.0,
            PixelFilter::Gaussian { stddev } => {
                let a = -0.5 / (f64::from(stddev) * f64::from(stddev));
                ((a * x * x).exp() - (a * r * r).exp()).max(0.0)
            }
            PixelFilter::Tent { .. } => 1.0 - x.abs() / r,
        }
    }

    /// The name `[film] filter` and Mitsuba give it.
    pub fn name(self) -> &'static str {
        match self {
            PixelFilter::Box => "box",
            PixelFilter::Gaussian { .. } => "gaussian",
            PixelFilter::Tent { .. } => "tent",
        }
    }
}

/// A pixel filter's size: `value` (or `default`) where it is in (0, max].
fn filter_size(value: Option<f32>, default: f32, max: f32) -> Result<f32, String> {
    let v = value.unwrap_or(default);
    if v > 0.0 && v <= max {
        Ok(v)
    } else {
        Err(format!("{v} is not in (0, {max}] pixels"))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Integrator {
    /// Longest path in segments: 1 sees emitters only, 2 adds direct light.
    pub max_depth: u32,
    /// Depth from which Russian roulette may end a path.
    pub rr_depth: u32,
    /// Whether emitters seen directly are hidden (Mitsuba's `hide_emitters`): camera rays
    /// pass through emitting meshes and find no environment; light reaches the scene
    /// from both as before.
    pub hide_emitters: bool,
}

/// A pinhole or orthographic camera with an orthonormal right-handed basis: it looks along
/// `forward`, `right = forward × up_hint`, `up = right × forward`.
#[derive(Clone, Debug)]
pub struct Sensor {
    pub origin: Vec3,
    pub look_at: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees (a pinhole camera's; kept but unused by an
    /// orthographic one).
    pub fov_y: f32,
    /// An orthographic camera's view height in world units (its width is that times the
    /// film's aspect ratio): its rays leave the plane through `origin` spanned by `right`
    /// and `up`, all along `forward`. `None`: a pinhole camera at `origin`.
    pub ortho_height: Option<f32>,
    /// A pinhole camera's thin lens (depth of field), if any.
    pub lens: Option<ThinLens>,
    pub target_image: Option<Texture>,
}

/// A thin lens in place of a pinhole (Mitsuba's `thinlens`): rays leave a disk of radius
/// `aperture_radius` around the camera's origin, perpendicular to its view, and what lies
/// at `focus_distance` along the view is sharp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThinLens {
    pub aperture_radius: f32,
    pub focus_distance: f32,
}

impl Sensor {
    /// The camera at `origin` looking at `target` with `up` as the up hint; `Err` names
    /// the degenerate input. `fov_y` is checked by the caller.
    pub fn looking_at(origin: Vec3, target: Vec3, up: Vec3, fov_y: f32) -> Result<Self, &'static str> {
        let forward = (target - origin).try_normalize().ok_or("origin and target coincide")?;
        // Nearly parallel vectors would give a basis dominated by rounding error.
        let right = forward.cross(up.normalize_or_zero());
        if right.length() < 1e-4 {
            return Err("up is zero or parallel to the view direction");
        }
        let right = right.normalize();
        Ok(Sensor { origin, look_at: target, forward, right, up: right.cross(forward), fov_y, ortho_height: None, lens: None, target_image: None })
    }

    /// The orthographic camera of view height `height` in place of this pinhole one.
    pub fn orthographic(self, height: f32) -> Self {
        Sensor { ortho_height: Some(height), ..self }
    }

    /// The ray (origin, unit direction) through normalised device coordinates `ndc` in
    /// [-1, 1]² (x right, y up), for a film of aspect ratio `aspect` = width / height, as
    /// the kernels' `camera_ray` casts it (a thin lens's from the lens's centre).
    pub fn ray(&self, ndc: Vec2, aspect: f32) -> (Vec3, Vec3) {
        match self.ortho_height {
            Some(h) => (self.origin + 0.5 * h * (ndc.x * aspect * self.right + ndc.y * self.up), self.forward),
            None => (self.origin, self.ray_direction(ndc, aspect)),
        }
    }

    /// A pinhole camera's unit direction through normalised device coordinates `ndc` in
    /// [-1, 1]² (x right, y up), for a film of aspect ratio `aspect` = width / height.
    pub fn ray_direction(&self, ndc: Vec2, aspect: f32) -> Vec3 {
        let t = (self.fov_y.to_radians() * 0.5).tan();
        (self.forward + ndc.x * t * aspect * self.right + ndc.y * t * self.up).normalize()
    }
}

/// An image loaded from a file named in the scene (or embedded in one: then `path` is the
/// scene file followed by `#` and where in it the image is).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub path: PathBuf,
    /// Shared between the values that use one image (a glTF emissive material's texture
    /// on each of its meshes), so that it is held, and uploaded, once.
    pub image: std::sync::Arc<Image>,
    /// How a lookup between texel centres reads the image.
    pub filter: Filter,
    /// What lies beyond [0, 1] in u and in v.
    pub wrap: [Wrap; 2],
    /// The set of texture coordinates the image is looked up at: 0, a mesh's `uvs` (glTF's
    /// `TEXCOORD_0`, OBJ's), or 1, its `uvs1` (glTF's `TEXCOORD_1`).
    pub uv_set: u32,
}

impl Texture {
    /// `image`, known by `path`, read bilinearly, repeating, at the first set of texture
    /// coordinates.
    pub fn new(path: PathBuf, image: std::sync::Arc<Image>) -> Self {
        Texture { path, image, filter: Filter::Bilinear, wrap: [Wrap::Repeat; 2], uv_set: 0 }
    }
}

/// What a texture holds beyond [0, 1] along one of its axes (and what its bilinear lookup
/// blends in beyond its edge texels' centres).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Wrap {
    /// The image again (TOML's default, glTF's REPEAT, Mitsuba's `repeat`).
    #[default]
    Repeat,
    /// The edge texels (glTF's CLAMP_TO_EDGE, Mitsuba's `clamp`).
    Clamp,
    /// The image mirrored, every other copy (glTF's MIRRORED_REPEAT, Mitsuba's `mirror`).
    Mirror,
}

impl Wrap {
    /// The name the TOML format gives the mode.
    pub fn name(self) -> &'static str {
        match self {
            Self::Repeat => "repeat",
            Self::Clamp => "clamp",
            Self::Mirror => "mirror",
        }
    }

    /// The mode TOML's `name` names.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Repeat, Self::Clamp, Self::Mirror].into_iter().find(|w| w.name() == name)
    }
}

/// A texture's reconstruction filter. Either way the image repeats beyond [0, 1]².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Filter {
    /// The four nearest texels, weighted bilinearly (TOML's default, glTF's LINEAR,
    /// Mitsuba's `bilinear`).
    #[default]
    Bilinear,
    /// The texel whose square holds the point (TOML's `filter = "nearest"`, glTF's
    /// NEAREST magnification filter, Mitsuba's `nearest`): a step at every texel edge.
    Nearest,
}

impl Filter {
    /// The name the TOML format gives the filter.
    pub fn name(self) -> &'static str {
        match self {
            Self::Bilinear => "bilinear",
            Self::Nearest => "nearest",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum ColorValue {
    Constant([f32; 3]),
    Texture(Texture),
}

/// A value that may be a texture: its filter and wrap modes, the defaults for a constant.
pub trait TextureValue {
    /// The texture, None for a constant.
    fn texture(&self) -> Option<&Texture>;

    /// The texture's filter ([`Filter::Bilinear`] for a constant).
    fn filter(&self) -> Filter {
        self.texture().map_or(Filter::Bilinear, |t| t.filter)
    }

    /// The texture's wrap modes in u and v (repeat for a constant).
    fn wrap(&self) -> [Wrap; 2] {
        self.texture().map_or([Wrap::Repeat; 2], |t| t.wrap)
    }

    /// The texture's set of texture coordinates (0 for a constant).
    fn uv_set(&self) -> u32 {
        self.texture().map_or(0, |t| t.uv_set)
    }
}

impl TextureValue for ColorValue {
    fn texture(&self) -> Option<&Texture> {
        if let Self::Texture(t) = self {
            Some(t)
        } else {
            None
        }
    }
}

impl ColorValue {
    /// Whether any channel of the constant, or of any texel, is above zero.
    pub fn any_positive(&self) -> bool {
        match self {
            Self::Constant(c) => c.iter().any(|&v| v > 0.0),
            Self::Texture(t) => t.image.data.iter().flatten().any(|&v| v > 0.0),
        }
    }
}

/// A scalar property; a texture's R channel holds it.
#[derive(Clone, Debug)]
pub enum ScalarValue {
    Constant(f32),
    Texture(Texture),
}

impl TextureValue for ScalarValue {
    fn texture(&self) -> Option<&Texture> {
        match self {
            Self::Constant(_) => None,
            Self::Texture(t) => Some(t),
        }
    }
}

/// A glTF metallic-roughness material. A diffuse one has roughness 1 and metallic 0, which
/// the file may not set. A dielectric (glass) is a smooth interface whose base colour is
/// its transmittance; its roughness and metallic are 0 and unused.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    pub base_color: ColorValue,
    pub roughness: ScalarValue,
    pub metallic: ScalarValue,
    /// Reflects nothing from behind (the clockwise side of its triangles), as Mitsuba's
    /// BSDFs not wrapped in `twosided`; otherwise both sides shade alike.
    pub one_sided: bool,
    /// Perturbs the shading normal by a normal map or a bump map (never optimised).
    pub perturbation: Option<Perturbation>,
    /// Cuts the surface out where its alpha is below a threshold (never optimised).
    pub alpha: Option<AlphaMask>,
    /// A dielectric's index of refraction, its interior (the back of its triangles; a thin
    /// dielectric's sheet) over its exterior, in [MIN_IOR, MAX_IOR] (never optimised); a
    /// plastic's coating's likewise; a principled material's sets its dielectric part's
    /// normal-incidence reflectance ((ior − 1)/(ior + 1))², 0.04 at [`DEFAULT_IOR`];
    /// [`DEFAULT_IOR`] and unused for the other kinds.
    pub ior: f32,
    /// A (refracting) dielectric's interior absorption coefficient per unit length, per
    /// channel, at least 0: a ray that travels a distance t inside keeps exp(−absorption t)
    /// of its radiance (never optimised). Zero for the other kinds.
    pub absorption: [f32; 3],
    /// A rough dielectric's or a conductor's distribution of microfacets
    /// ([`Distribution::Ggx`] for the other kinds).
    pub distribution: Distribution,
    /// A conductor's complex index of refraction eta + i k per channel, relative to the
    /// medium outside (never optimised); zero for the other kinds.
    pub eta: [f32; 3],
    pub k: [f32; 3],
    /// A plastic's `nonlinear`: its base's reflectance scales the internal reflections
    /// too (never optimised); false for the other kinds.
    pub nonlinear: bool,
    /// A plastic's coating is layered (true, Mitsuba 3's `roughplastic`): the light that
    /// enters it is reflected back and forth between coating and base. False: the base is
    /// seen through two smooth refractions and nothing more (Mitsuba 3's `pplastic`). True
    /// for the other kinds.
    pub layered: bool,
    /// A plastic's specular tint per channel (Mitsuba's `specular_reflectance`): it scales
    /// the coating's reflection, 1 by default (never optimised). 1 for the other kinds.
    pub specular: [f32; 3],
}

/// The distribution of a rough dielectric's, a conductor's or a plastic's microfacet
/// normals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Distribution {
    /// Trowbridge–Reitz (GGX), as the principled model's.
    #[default]
    Ggx,
    /// Beckmann's (Mitsuba 3's default for `roughdielectric` and `roughconductor`).
    Beckmann,
}

impl Distribution {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ggx => "ggx",
            Self::Beckmann => "beckmann",
        }
    }
}

impl Material {
    /// A Lambertian material of reflectance `base_color`, both sides alike.
    pub fn diffuse(name: &str, base_color: ColorValue) -> Self {
        Self {
            name: name.to_string(),
            kind: MaterialKind::Diffuse,
            base_color,
            roughness: ScalarValue::Constant(1.0),
            metallic: ScalarValue::Constant(0.0),
            one_sided: false,
            perturbation: None,
            alpha: None,
            ior: DEFAULT_IOR,
            absorption: [0.0; 3],
            distribution: Distribution::Ggx,
            eta: [0.0; 3],
            k: [0.0; 3],
            nonlinear: false,
            layered: true,
            specular: [1.0; 3],
        }
    }

    /// Glass of `kind` (any dielectric kind) with transmittance `base_color` and index of
    /// refraction `ior`: no metallic, normal map or alpha, both sides alike, roughness 0 and
    /// GGX (a rough dielectric's caller sets its own).
    pub fn glass(name: String, kind: MaterialKind, base_color: ColorValue, ior: f32) -> Self {
        debug_assert!(kind.is_dielectric());
        Self {
            name,
            kind,
            base_color,
            roughness: ScalarValue::Constant(0.0),
            metallic: ScalarValue::Constant(0.0),
            one_sided: false,
            perturbation: None,
            alpha: None,
            ior,
            absorption: [0.0; 3],
            distribution: Distribution::Ggx,
            eta: [0.0; 3],
            k: [0.0; 3],
            nonlinear: false,
            layered: true,
            specular: [1.0; 3],
        }
    }
}

impl Material {
    /// A conductor with specular tint `base_color`, `roughness`, `distribution` and complex
    /// index of refraction `eta` + i `k`: no metallic, normal map or alpha.
    pub fn conductor(
        name: String,
        base_color: ColorValue,
        roughness: ScalarValue,
        distribution: Distribution,
        [eta, k]: [[f32; 3]; 2],
        one_sided: bool,
    ) -> Self {
        Self {
            name,
            kind: MaterialKind::Conductor,
            base_color,
            roughness,
            metallic: ScalarValue::Constant(0.0),
            one_sided,
            perturbation: None,
            alpha: None,
            ior: DEFAULT_IOR,
            absorption: [0.0; 3],
            distribution,
            eta,
            k,
            nonlinear: false,
            layered: true,
            specular: [1.0; 3],
        }
    }

    /// A plastic with diffuse reflectance `base_color` under a coating of index `ior`
    /// (interior over exterior) on microfacets of `roughness` (a constant: the coating's
    /// transmittance is tabulated for it) and `distribution`: no metallic, normal map or
    /// alpha, linear and two-sided (set `nonlinear` and `one_sided` after).
    pub fn plastic(name: String, base_color: ColorValue, roughness: f32, distribution: Distribution, ior: f32) -> Self {
        let (nonlinear, one_sided) = (false, false);
        Self {
            name,
            kind: MaterialKind::Plastic,
            base_color,
            roughness: ScalarValue::Constant(roughness),
            metallic: ScalarValue::Constant(0.0),
            one_sided,
            perturbation: None,
            alpha: None,
            ior,
            absorption: [0.0; 3],
            distribution,
            eta: [0.0; 3],
            k: [0.0; 3],
            nonlinear,
            layered: true,
            specular: [1.0; 3],
        }
    }
}

/// The complex index of refraction (eta, k) per linear RGB channel of the metals and other
/// materials that Mitsuba 3 names for its conductors, as its RGB variants reduce the
/// measured spectra (so that a named conductor renders as it does in Mitsuba). "none" is
/// a perfect mirror (reflectance 1 at every angle).
pub const METALS: [(&str, [f32; 3], [f32; 3]); 72] = [
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    ("a-C", [2.94405, 2.22714, 1.96816], [0.887465, 0.799299, 0.81529]),
    ("Ag", [0.155276, 0.116728, 0.138388], [4.82835, 3.12222, 2.1469]),
    ("Al", [1.6575, 0.880405, 0.521244], [9.22381, 6.2695, 4.837]),
    ("AlAs", [3.6053, 3.23294, 2.21632], [0.000679437, 0.0, 0.00751271]),
    ("AlAs_palik", [3.6053, 3.23294, 2.21632], [0.000679437, 0.0, 0.00751271]),
    ("AlSb", [0.0, 4.13937, 4.66925], [0.0, 0.0940091, 1.30057]),
    ("AlSb_palik", [0.0, 4.13937, 4.66925], [0.0, 0.0940091, 1.30057]),
    ("Au", [0.143036, 0.375307, 1.44205], [3.983, 2.38556, 1.60336]),
    ("Be", [4.18501, 3.18503, 2.78406], [3.83547, 3.01012, 2.86899]),
    ("Be_palik", [4.18501, 3.18503, 2.78406], [3.83547, 3.01012, 2.86899]),
    ("Cr", [4.36967, 2.91651, 1.6549], [5.20655, 4.23131, 3.7547]),
    ("CsI", [2.1449, 1.70232, 1.66243], [0.0, 0.0, 0.0]),
    ("CsI_palik", [2.1449, 1.70232, 1.66243], [0.0, 0.0, 0.0]),
    ("Cu", [0.201005, 0.92375, 1.10222], [3.91326, 2.45305, 2.14209]),
    ("Cu2O", [3.55177, 2.94987, 2.75188], [0.114207, 0.193897, 0.606134]),
    ("Cu2O_palik", [3.55177, 2.94987, 2.75188], [0.114207, 0.193897, 0.606134]),
    ("Cu_palik", [0.213229, 0.919715, 1.10241], [3.92187, 2.45733, 2.13658]),
    ("CuO", [3.24754, 2.44781, 2.21022], [0.52109, 0.570031, 0.722179]),
    ("CuO_palik", [3.24754, 2.44781, 2.21022], [0.52109, 0.570031, 0.722179]),
    ("d-C", [2.70872, 2.31883, 2.2289], [0.0, 0.0, 0.0]),
    ("d-C_palik", [2.70872, 2.31883, 2.2289], [0.0, 0.0, 0.0]),
    ("Hg", [2.39894, 1.44003, 0.90957], [6.32759, 4.37192, 3.42176]),
    ("Hg_palik", [2.39894, 1.44003, 0.90957], [6.32759, 4.37192, 3.42176]),
    ("HgTe", [4.77904, 3.2312, 2.6599], [1.63161, 1.58081, 1.72929]),
    ("HgTe_palik", [4.77904, 3.2312, 2.6599], [1.63161, 1.58081, 1.72929]),
    ("Ir", [3.0863, 2.08219, 1.61791], [5.59215, 4.06709, 3.26731]),
    ("Ir_palik", [3.0863, 2.08219, 1.61791], [5.59215, 4.06709, 3.26731]),
    ("K", [0.0640432, 0.0464098, 0.0381849], [2.1042, 1.34894, 0.913126]),
    ("K_palik", [0.0640432, 0.0464098, 0.0381849], [2.1042, 1.34894, 0.913126]),
    ("Li", [0.265791, 0.195618, 0.220949], [3.54015, 2.31112, 1.66861]),
    ("Li_palik", [0.265791, 0.195618, 0.220949], [3.54015, 2.31112, 1.66861]),
    ("MgO", [2.08958, 1.65072, 1.59488], [4.3327e-12, 0.0, 2.49865e-11]),
    ("MgO_palik", [2.08958, 1.65072, 1.59488], [4.3327e-12, 0.0, 2.49865e-11]),
    ("Mo", [4.48397, 3.52513, 2.77631], [4.11144, 3.42083, 3.15061]),
    ("Mo_palik", [4.48397, 3.52513, 2.77631], [4.11144, 3.42083, 3.15061]),
    ("Na_palik", [0.0602694, 0.0561409, 0.0619884], [3.17927, 2.11249, 1.57904]),
    ("Nb", [3.42007, 2.79009, 2.39563], [3.44139, 2.73767, 2.57975]),
    ("Nb_palik", [3.42007, 2.79009, 2.39563], [3.44139, 2.73767, 2.57975]),
    ("Ni_palik", [2.3673, 1.66337, 1.46708], [4.49881, 3.05015, 2.34544]),
    ("Rh", [2.58579, 1.86022, 1.55426], [6.78226, 4.70299, 3.97607]),
    ("Rh_palik", [2.58579, 1.86022, 1.55426], [6.78226, 4.70299, 3.97607]),
    ("Se", [4.05831, 2.84294, 2.82085], [0.75405, 0.638444, 0.521808]),
    ("Se-e", [5.72285, 4.16574, 4.08134], [0.871136, 1.10516, 1.56532]),
    ("Se-e_palik", [5.72285, 4.16574, 4.08134], [0.871136, 1.10516, 1.56532]),
    ("Se_palik", [4.05831, 2.84294, 2.82085], [0.75405, 0.638444, 0.521808]),
    ("SiC", [3.17234, 2.52597, 2.47937], [7.53766e-07, 0.0, 1.01925e-05]),
    ("SiC_palik", [3.17234, 2.52597, 2.47937], [7.53766e-07, 0.0, 1.01925e-05]),
    ("SnTe", [4.52425, 1.98164, 1.28159], [0.0, 0.0, 0.0]),
    ("SnTe_palik", [4.52425, 1.98164, 1.28159], [0.0, 0.0, 0.0]),
    ("Ta", [2.06272, 2.39294, 2.62793], [2.40836, 1.74149, 1.94703]),
    ("Ta_palik", [2.06272, 2.39294, 2.62793], [2.40836, 1.74149, 1.94703]),
    ("Te", [7.39023, 4.4821, 2.63711], [3.25602, 3.52706, 3.29205]),
    ("Te-e", [7.50891, 4.29643, 2.36999], [5.58393, 4.94721, 3.99759]),
    ("Te-e_palik", [7.50891, 4.29643, 2.36999], [5.58393, 4.94721, 3.99759]),
    ("Te_palik", [7.39023, 4.4821, 2.63711], [3.25602, 3.52706, 3.29205]),
    ("ThF4", [1.83071, 1.44223, 1.38765], [0.0, 0.0, 0.0]),
    ("ThF4_palik", [1.83071, 1.44223, 1.38765], [0.0, 0.0, 0.0]),
    ("TiC", [3.70053, 2.83742, 2.58229], [3.26564, 2.35159, 2.17279]),
    ("TiC_palik", [3.70053, 2.83742, 2.58229], [3.26564, 2.35159, 2.17279]),
    ("TiN", [1.64845, 1.15052, 1.37982], [3.36833, 1.9435, 1.10207]),
    ("TiN_palik", [1.64845, 1.15052, 1.37982], [3.36833, 1.9435, 1.10207]),
    ("TiO2", [3.45661, 2.80174, 2.90517], [0.000105265, 0.0, 0.000652887]),
    ("TiO2-e", [3.10656, 2.51317, 2.58244], [2.97516e-05, 0.0, 0.000182698]),
    ("TiO2-e_palik", [3.10656, 2.51317, 2.58244], [2.97516e-05, 0.0, 0.000182698]),
    ("TiO2_palik", [3.45661, 2.80174, 2.90517], [0.000105265, 0.0, 0.000652887]),
    ("V_palik", [4.27758, 3.51295, 2.76107], [3.4913, 2.88945, 3.11152]),
    ("VC", [3.65757, 2.75274, 2.53267], [3.0683, 2.19869, 1.96319]),
    ("VC_palik", [3.65757, 2.75274, 2.53267], [3.0683, 2.19869, 1.96319]),
    ("VN", [2.8656, 2.11919, 1.94009], [3.03224, 2.05612, 1.61631]),
    ("VN_palik", [2.8656, 2.11919, 1.94009], [3.03224, 2.05612, 1.61631]),
    ("W", [4.37082, 3.30025, 2.99841], [3.50064, 2.60487, 2.27323]),
];

/// The complex index of refraction of the metal `name` in [`METALS`].
pub fn metal(name: &str) -> Option<[[f32; 3]; 2]> {
    METALS.iter().find(|(n, _, _)| *n == name).map(|(_, eta, k)| [*eta, *k])
}

/// An alpha test: whether the surface is there at a point, by its alpha there (looked up
/// bilinearly, for a texture, at the point's texture coordinates). Where it is not, rays
/// pass through it as if it were not there.
#[derive(Clone, Debug)]
pub struct AlphaMask {
    /// In [0, 1]; a texture's R channel holds it.
    pub value: ScalarValue,
    pub mode: AlphaMode,
}

/// How an alpha decides whether the surface is there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AlphaMode {
    /// Where the alpha is at least `cutoff` (glTF's `MASK`): a cut-out.
    Mask { cutoff: f32 },
    /// With probability alpha, drawn anew for each ray that reaches the point (glTF's
    /// `BLEND`, Mitsuba's `mask`): a coverage, which in expectation lets 1 − alpha of the
    /// light through.
    Blend,
}

impl AlphaMask {
    /// Whether the surface is there at every point for every ray: every texel (so every
    /// bilinear lookup) at or above the cutoff, or for a blend at 1.
    pub fn never_cuts(&self) -> bool {
        let there = |a: f32| match self.mode {
            AlphaMode::Mask { cutoff } => a >= cutoff,
            AlphaMode::Blend => a >= 1.0,
        };
        match &self.value {
            ScalarValue::Constant(a) => there(*a),
            ScalarValue::Texture(t) => t.image.data.iter().all(|p| there(p[0])),
        }
    }
}

impl AlphaMode {
    /// The TOML name (`alpha_mode`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mask { .. } => "mask",
            Self::Blend => "blend",
        }
    }
}

/// A tangent-space normal map: each texel's RGB in [0, 1] encodes the unit normal
/// (2R − 1, 2G − 1, 2B − 1) with x along the surface's tangent (the direction of increasing
/// u), y along its bitangent and z along the interpolated normal, as glTF's
/// `normalTexture` and Mitsuba's `normalmap` store it; `scale` multiplies x and y (glTF's
/// `normalTexture.scale`).
#[derive(Clone, Debug)]
pub struct NormalMap {
    pub texture: Texture,
    pub scale: f32,
    pub bitangent: Bitangent,
}

/// What perturbs a material's shading normal: one map, never both.
#[derive(Clone, Debug)]
pub enum Perturbation {
    Normal(NormalMap),
    Bump(BumpMap),
}

impl Perturbation {
    /// The map's texture.
    pub fn texture(&self) -> &Texture {
        match self {
            Self::Normal(n) => &n.texture,
            Self::Bump(b) => &b.texture,
        }
    }

    /// What the map is called in messages: "normal map" or "bump map".
    pub fn what(&self) -> &'static str {
        match self {
            Self::Normal(_) => "normal map",
            Self::Bump(_) => "bump map",
        }
    }
}

/// A bump map: the surface seen as displaced along its normal by the height
/// `scale` × h(u, v), h the texture's value (an RGB texel's luminance, as Mitsuba's
/// `bumpmap` reads it), interpolated as the texture's filter says. The shading normal
/// becomes that of the displaced surface to first order, n − ∇h projected as Mitsuba's
/// `bumpmap` does (the texture coordinates' world-space gradients taken on each triangle).
/// A nearest-filtered height field is flat between texel edges: it perturbs nothing.
#[derive(Clone, Debug)]
pub struct BumpMap {
    pub texture: Texture,
    pub scale: f32,
}

impl BumpMap {
    /// The heights scale × luminance, one per texel.
    pub fn heights(&self) -> Vec<f32> {
        // Mitsuba's `luminance` weights (sRGB primaries, summing to 1), to the digits it uses.
        self.texture.image.data.iter().map(|p| self.scale * (0.212671 * p[0] + 0.715160 * p[1] + 0.072169 * p[2])).collect()
    }
}

/// Which way a normal map's y points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bitangent {
    /// Along increasing v, the image's up: cross(n, tangent) turned where the texture
    /// coordinates are mirrored (glTF's convention, MikkTSpace's handedness).
    Uv,
    /// cross(n, tangent) everywhere (Mitsuba's `normalmap`).
    Cross,
}

impl Bitangent {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Uv => "uv",
            Self::Cross => "cross",
        }
    }
}

impl NormalMap {
    /// The decoded, scaled tangent-space vectors (not normalised: the kernels normalise
    /// after filtering).
    pub fn vectors(&self) -> Vec<[f32; 3]> {
        self.texture.image.data.iter().map(|p| [(2.0 * p[0] - 1.0) * self.scale, (2.0 * p[1] - 1.0) * self.scale, 2.0 * p[2] - 1.0]).collect()
    }
}

impl Material {
    pub fn is_textured(&self) -> bool {
        matches!(self.base_color, ColorValue::Texture(_))
            || matches!(self.roughness, ScalarValue::Texture(_))
            || matches!(self.metallic, ScalarValue::Texture(_))
    }

    /// Every texture the material looks up: its values', its map's and its alpha's.
    pub fn textures(&self) -> impl Iterator<Item = &Texture> {
        let alpha = self.alpha.as_ref().and_then(|a| a.value.texture());
        [self.base_color.texture(), self.roughness.texture(), self.metallic.texture(), self.perturbation.as_ref().map(Perturbation::texture), alpha]
            .into_iter()
            .flatten()
    }

    /// The normal map, where one perturbs the shading normal.
    pub fn normal_map(&self) -> Option<&NormalMap> {
        match &self.perturbation {
            Some(Perturbation::Normal(n)) => Some(n),
            _ => None,
        }
    }

    /// The bump map, where one perturbs the shading normal.
    pub fn bump_map(&self) -> Option<&BumpMap> {
        match &self.perturbation {
            Some(Perturbation::Bump(b)) => Some(b),
            _ => None,
        }
    }
}

impl Mesh {
    /// A mesh of `positions` and triangles `indices` (counter-clockwise from the front)
    /// with material `material` (an index into the scene's materials): no normals, texture
    /// coordinates or emission.
    pub fn new(name: &str, positions: Vec<[f32; 3]>, indices: Vec<[u32; 3]>, material: usize) -> Self {
        Mesh {
            name: name.to_string(),
            path: PathBuf::from(format!("{name} (built in code)")),
            positions,
            normals: Vec::new(),
            uvs: Vec::new(),
            uvs1: Vec::new(),
            indices,
            material,
            emission: ColorValue::Constant([0.0; 3]),
            two_sided_emission: false,
            sphere: None,
        }
    }
}

impl Mesh {
    /// Whether the mesh has texture coordinate set `set` (0: `uvs`, 1: `uvs1`).
    pub fn has_uvs(&self, set: u32) -> bool {
        !if set == 1 { &self.uvs1 } else { &self.uvs }.is_empty()
    }

    /// The second set of texture coordinates at each triangle's corners, in triangle order
    /// (empty where the mesh has none): what a scene file's `uv1` array holds.
    pub fn corner_uvs1(&self) -> Vec<[[f32; 2]; 3]> {
        if self.uvs1.is_empty() {
            return Vec::new();
        }
        self.indices.iter().map(|t| t.map(|i| self.uvs1[i as usize])).collect()
    }

    /// Gives the mesh the second set of texture coordinates `corners` (one per triangle
    /// corner, [`Self::corner_uvs1`]), splitting a vertex whose corners differ in it.
    pub fn set_corner_uvs1(&mut self, corners: &[[[f32; 2]; 3]]) {
        let mut uvs1: Vec<Option<[f32; 2]>> = vec![None; self.positions.len()];
        for (t, corner) in self.indices.iter_mut().zip(corners) {
            for (i, &uv) in t.iter_mut().zip(corner) {
                match uvs1[*i as usize] {
                    None => uvs1[*i as usize] = Some(uv),
                    Some(have) if have == uv => {}
                    Some(_) => {
                        let v = *i as usize;
                        self.positions.push(self.positions[v]);
                        if !self.normals.is_empty() {
                            self.normals.push(self.normals[v]);
                        }
                        if !self.uvs.is_empty() {
                            self.uvs.push(self.uvs[v]);
                        }
                        *i = (uvs1.len()) as u32;
                        uvs1.push(Some(uv));
                    }
                }
            }
        }
        self.uvs1 = uvs1.into_iter().map(Option::unwrap_or_default).collect();
    }
}

/// A triangle mesh in world space. UVs follow the OBJ convention (v pointing up, (0, 0)
/// the bottom left of an image); importers convert theirs.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub name: String,
    /// The file the triangles came from.
    pub path: PathBuf,
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    /// A second set of texture coordinates (glTF's `TEXCOORD_1`), per vertex as `uvs`;
    /// empty where the mesh has none. Textures whose `uv_set` is 1 read it.
    pub uvs1: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    pub material: usize,
    /// Radiance emitted from the front (counter-clockwise) side, or both sides when
    /// `two_sided_emission`: a colour, or a texture read with the mesh's texture coordinates.
    pub emission: ColorValue,
    pub two_sided_emission: bool,
    /// The sphere that the triangles tessellate (their vertices on it), where the mesh
    /// stands for one: an emitting one is then sampled by the solid angle it subtends.
    pub sphere: Option<Sphere>,
}

/// A sphere in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub center: [f32; 3],
    pub radius: f32,
}

/// How a spot light's intensity falls off between its inner and outer cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpotFalloff {
    /// glTF's (KHR_lights_punctual): the square of a linear ramp in cos θ.
    Smooth,
    /// Mitsuba's: linear in the angle θ.
    Linear,
}

impl SpotFalloff {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Smooth => "smooth",
            Self::Linear => "linear",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Radiant intensity `color × intensity` in every direction from `position`.
    Point,
    /// A point light restricted to a cone around `direction`: full intensity inside
    /// `inner` radians of the axis, none beyond `outer`.
    Spot { inner: f32, outer: f32, falloff: SpotFalloff },
    /// Irradiance `color × intensity` on a surface facing the light, arriving along
    /// `direction` from infinitely far away.
    Directional,
}

impl LightKind {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Point => "point",
            Self::Spot { .. } => "spot",
            Self::Directional => "directional",
        }
    }
}

/// A delta light (no area, so never hit by a ray): sampled by next-event estimation only.
/// Its emitted quantity (radiant intensity, or irradiance for a directional light) is
/// `color × intensity`; both factors can be optimised.
#[derive(Clone, Debug)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    pub position: Vec3,
    /// Unit direction the light travels along (spot axis, directional light's rays).
    pub direction: Vec3,
    pub color: [f32; 3],
    pub intensity: f32,
}

/// Light from infinitely far away: radiance `value * scale`, a texture being a lat-long map.
/// A scene without `[environment]` has a black one.
#[derive(Clone, Debug)]
pub struct Environment {
    pub value: ColorValue,
    pub scale: f32,
}

/// An axis-aligned box filled with a medium (or the part of it inside a closed mesh,
/// `boundary`): a ray through it keeps exp(−∫σ) of what lies
/// behind, where σ = `scale` × density. With `albedo` 0 it absorbs and emits (a ray gains
/// ∫ σ·L_e·exp(−∫σ)); with `albedo` above 0 it scatters that part of what it stops by a
/// Henyey–Greenstein phase function of asymmetry `g`, and emits nothing. Density and
/// emission are constants or 3-D grids over the box, looked up trilinearly between voxel
/// centres (clamped at the faces).
#[derive(Clone, Debug, PartialEq)]
pub struct Medium {
    pub name: String,
    /// The box's corners in world space, `min` below `max` on every axis.
    pub min: [f32; 3],
    pub max: [f32; 3],
    /// The density before `scale`: one channel, [`crate::tensor::Shape::constant`] or
    /// a grid (x along the box's x axis, fastest in memory).
    pub density: crate::tensor::ParamValue,
    /// The radiance emitted per unit of absorbed light: three channels, constant or a grid.
    pub emission: crate::tensor::ParamValue,
    /// Extinction per unit length of density 1.
    pub scale: f32,
    /// The ray-marching step, in voxels of the finer of the two grids (a constant counts
    /// as one voxel across the box).
    pub step: f32,
    /// The part of the extinction that scatters, per channel, in [0, 1]: 0 absorbs only.
    /// Three channels, constant or a grid.
    pub albedo: crate::tensor::ParamValue,
    /// The phase function's mean cosine, in (−1, 1): 0 isotropic, above 0 forward.
    pub g: f32,
    /// A scattering medium's density bound for tracking, fixed (at least the density's
    /// values and its parameter's range top); None: the density's largest value, taken
    /// again before each pass from the parameters it renders.
    pub majorant: Option<f32>,
    /// The file formats the density's, the emission's and the albedo's grids came in
    /// (`.npy` for a constant): the recovered scene writes each grid back in its own.
    pub formats: [GridFormat; 3],
    /// The closed mesh that bounds the medium in its box: the medium is the part of the
    /// box inside it. None: the whole box.
    pub boundary: Option<MediumBoundary>,
}

/// A closed mesh around a medium, in world space: every edge borders two triangles, wound
/// alike, so that `(v1 − v0) × (v2 − v0)` points out (checked and turned so by
/// [`MediumBoundary::new`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MediumBoundary {
    pub positions: Vec<[f32; 3]>,
    pub indices: Vec<[u32; 3]>,
}

/// The file format of a medium's grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GridFormat {
    /// numpy's `.npy`, shape [z, y, x] or [z, y, x, channels].
    #[default]
    Npy,
    /// Mitsuba's `.vol` ([`crate::vol`]).
    Vol,
}

impl GridFormat {
    /// The format a grid file's name gives: `.vol` (any case) is Mitsuba's, any other `.npy`.
    pub fn of(path: &str) -> GridFormat {
        if std::path::Path::new(path).extension().is_some_and(|e| e.eq_ignore_ascii_case("vol")) {
            GridFormat::Vol
        } else {
            GridFormat::Npy
        }
    }

    /// The extension of its files, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            GridFormat::Npy => "npy",
            GridFormat::Vol => "vol",
        }
    }
}

impl Medium {
    /// Whether it scatters (an albedo above 0 in some channel): it then emits nothing.
    pub fn scatters(&self) -> bool {
        self.albedo.data.iter().any(|&a| a > 0.0)
    }

    /// The step in world units along a ray: `step` voxels of the finest grid's smallest voxel side.
    pub fn world_step(&self) -> f32 {
        let mut side = f32::INFINITY;
        for v in [&self.density, &self.emission] {
            let dims = v.shape.dims();
            for axis in 0..3 {
                let n = if dims.len() == 3 { dims[2 - axis] } else { 1 };
                side = side.min((self.max[axis] - self.min[axis]) / n as f32);
            }
        }
        self.step * side
    }
}

/// What an optimised parameter stands for. Indices are into `Scene::materials` / `meshes`
/// / `lights`. An environment parameter replaces the environment's value before `scale`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParamTarget {
    BaseColor {
        material: usize,
    },
    Roughness {
        material: usize,
    },
    Metallic {
        material: usize,
    },
    Emission {
        mesh: usize,
    },
    Environment,
    LightColor {
        light: usize,
    },
    LightIntensity {
        light: usize,
    },
    /// A medium's density (before its `scale`): one channel, a constant or a grid.
    MediumDensity {
        medium: usize,
    },
    /// A medium's emitted radiance: three channels, a constant or a grid.
    MediumEmission {
        medium: usize,
    },
    /// A scattering medium's albedo: three channels in [0, 1], a constant or a grid.
    MediumAlbedo {
        medium: usize,
    },
}

/// The scene's own value of a parameter, against which parameter error is measured.
#[derive(Clone, Debug)]
pub enum Reference {
    /// One value per channel.
    Constant(Vec<f32>),
    /// A texture in the scene; its resolution may differ from the parameter's.
    Texture(Texture),
    /// A medium's grid (or constant); its resolution may differ from the parameter's.
    Grid(crate::tensor::ParamValue),
}

#[derive(Clone, Debug)]
pub struct Param {
    /// The target as written, e.g. `materials.wall.base_color`; unique within a scene.
    pub name: String,
    pub target: ParamTarget,
    /// A constant of the target's channels, or a texture of them (`texture = [w, h]`).
    pub shape: crate::tensor::Shape,
    /// Start values, `shape.len()` floats: a scalar `init` repeated for every channel and
    /// texel, a colour for every texel, or an image's texels row by row (the image
    /// resampled to the texture's size).
    pub init: Vec<f32>,
    /// Inclusive bounds, `range[0] < range[1]`.
    pub range: [f32; 2],
    /// Learning rate for this parameter instead of the run's `lr` (unless a rate given
    /// outside the scene replaces it).
    pub lr: Option<f32>,
    pub reference: Reference,
}

/// The scene's `[optimise]` table: its layer of run settings (checked, not resolved: the
/// command line and job files may override them) and the optimised parameters.
#[derive(Clone, Debug, Default)]
pub struct Optimise {
    pub settings: crate::settings::Settings,
    pub params: Vec<Param>,
    /// The earlier run's `params.json` the parameters start from instead of their `init`
    /// ([`Scene::start_from_run`]), if any.
    pub started_from: Option<std::path::PathBuf>,
}

/// Where a scene came from, for writing it back: the TOML alone, or the glTF or Mitsuba
/// file it is or imports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Source {
    #[default]
    Toml,
    Gltf(GltfSource),
    Mitsuba(PathBuf),
}

/// An imported glTF file and where the model's imported materials and lights are in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GltfSource {
    pub path: PathBuf,
    /// glTF material index of each imported material, in model order (`None`: glTF's
    /// default material); materials after these came from the TOML.
    pub materials: Vec<Option<usize>>,
    /// `KHR_lights_punctual` index of each imported light, in model order.
    pub lights: Vec<usize>,
}

/// A loaded, validated scene; see the module documentation for its invariants.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    pub source: Source,
    pub film: Film,
    /// The film's pixel filter (`[film] filter`).
    pub pixel_filter: PixelFilter,
    pub integrator: Integrator,
    pub sensors: Vec<Sensor>,
    pub materials: Vec<Material>,
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub environment: Environment,
    /// Boxes of emitting and absorbing medium, in the order of the file's `[[media]]`.
    pub media: Vec<Medium>,
    pub optimise: Optimise,
    /// What loading approximated or left out, one line each (printed by the command line).
    pub warnings: Vec<String>,
    pub(super) content_hash: u64,
}

/// All meshes as one triangle list, for the BVH builder and the GPU. Vertex arrays are
/// parallel; a zero normal means "use the face normal", a mesh without UVs gets zeros.
#[derive(Clone, Debug, Default)]
pub struct SceneGeometry {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    /// The second set of texture coordinates, a mesh without one giving its first set;
    /// empty where no mesh has one.
    pub uvs1: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    pub triangle_material: Vec<u32>,
    pub triangle_mesh: Vec<u32>,
}

impl SceneGeometry {
    /// The texture coordinates that texture coordinate set `set` reads, per vertex: the
    /// second set where it is 1 and any mesh has one, else the first.
    pub fn uvs_of(&self, set: u32) -> &[[f32; 2]] {
        if set == 1 && !self.uvs1.is_empty() {
            &self.uvs1
        } else {
            &self.uvs
        }
    }
}

impl Scene {
    /// Directory that relative paths in the scene file, and cached targets, live in.
    pub fn dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new(""))
    }

    /// A hash of everything that determines the reference rendering (see
    /// the `hash` module): stable across runs and platforms, so it can key a cache of
    /// rendered targets.
    pub fn content_hash(&self) -> u64 {
        self.content_hash
    }

    pub fn material_index(&self, name: &str) -> Option<usize> {
        self.materials.iter().position(|m| m.name == name)
    }

    pub fn mesh_index(&self, name: &str) -> Option<usize> {
        self.meshes.iter().position(|m| m.name == name)
    }

    pub fn light_index(&self, name: &str) -> Option<usize> {
        self.lights.iter().position(|l| l.name == name)
    }

    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.indices.len()).sum()
    }

    /// Concatenates all meshes, in order, into one [`SceneGeometry`].
    pub fn flatten(&self) -> SceneGeometry {
        let mut g = SceneGeometry::default();
        let any_uvs1 = self.meshes.iter().any(|m| !m.uvs1.is_empty());
        for (mesh_id, mesh) in self.meshes.iter().enumerate() {
            let base = g.positions.len() as u32;
            let n = mesh.positions.len();
            g.positions.extend_from_slice(&mesh.positions);
            if mesh.normals.is_empty() {
                g.normals.resize(g.normals.len() + n, [0.0; 3]);
            } else {
                g.normals.extend_from_slice(&mesh.normals);
            }
            let first = g.uvs.len();
            if mesh.uvs.is_empty() {
                g.uvs.resize(g.uvs.len() + n, [0.0; 2]);
            } else {
                g.uvs.extend_from_slice(&mesh.uvs);
            }
            if any_uvs1 {
                if mesh.uvs1.is_empty() {
                    g.uvs1.extend_from_slice(&g.uvs[first..]);
                } else {
                    g.uvs1.extend_from_slice(&mesh.uvs1);
                }
            }
            g.indices.extend(mesh.indices.iter().map(|t| t.map(|i| i + base)));
            let count = mesh.indices.len();
            g.triangle_material.extend(std::iter::repeat_n(mesh.material as u32, count));
            g.triangle_mesh.extend(std::iter::repeat_n(mesh_id as u32, count));
        }
        g
    }
}

/// What an imported glTF or Mitsuba file contributes: its sensors, materials, meshes
/// (whose material indices are into `materials`) and lights, all checked by the importer,
/// and the film, depths and environment it suggests, which the TOML may override.
#[derive(Default)]
pub(crate) struct Imported {
    pub source: Source,
    pub film: Option<Film>,
    pub max_depth: Option<u32>,
    pub rr_depth: Option<u32>,
    pub hide_emitters: Option<bool>,
    pub pixel_filter: Option<PixelFilter>,
    pub sensors: Vec<Sensor>,
    pub materials: Vec<Material>,
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub environment: Option<Environment>,
    pub media: Vec<Medium>,
    /// One line each: what the import approximated or left out.
    pub warnings: Vec<String>,
}
