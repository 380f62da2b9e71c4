//! A scene on a device, ready to render and differentiate: its optimised parameters read
//! and set by name, images of any sensor, and the parameters' gradients for an image-space
//! adjoint (the primitive a loss of the caller's own needs) or for a built-in loss.

use crate::device::Device;
use crate::error::{Error, Result};
use crate::gpu::{CommandBuffer, MemoryKind};
use crate::image::Image;
use crate::ops::BufferOps;
use crate::render::gradient::{GradientInputs, GradientPass};
use crate::render::{GpuScene, PrimalRenderer};
use crate::scene::Scene;
use crate::settings::{gpu_seed, Loss};
use crate::tensor::{ParamValue, Shape};
use std::cell::RefCell;

/// What to render: which sensor, how many samples per pixel and with which seed (the same
/// seed and sample count give the same image).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderOptions {
    pub sensor: u32,
    pub spp: u32,
    pub seed: u64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions { sensor: 0, spp: 64, seed: 0 }
    }
}

/// An optimised parameter of a scene: its name (the target of its `[[optimise.params]]`
/// entry, e.g. `materials.wall.base_color`), shape and range.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamInfo {
    pub name: String,
    pub shape: Shape,
    /// Inclusive bounds; a value set outside them is clamped into them.
    pub range: [f32; 2],
}

/// The gradient estimate's passes, built on the first gradient and kept: buffers per
/// sensor, and the gradient they add into.
struct Gradients {
    pass: GradientPass,
    ops: BufferOps,
    /// The sum over a random half of the pixels, for the pass built to split
    /// ([`Renderer::gradient_with_half`]).
    half: Option<crate::gpu::Buffer>,
}

/// A scene uploaded to a device: the BVH built, the kernels specialised for it, and its
/// optimised parameters in one buffer, at the scene's own values to begin with.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::{Config, Device, Image, Renderer, RenderOptions, Scene};
/// let device = Device::new(&Config::from_env().0)?;
/// let scene = Scene::load("scenes/cornell/scene.toml")?;
/// let mut renderer = Renderer::new(&device, &scene)?;
/// let names: Vec<String> = renderer.params().into_iter().map(|p| p.name).collect();
/// assert_eq!(names, ["materials.red.base_color"]);
/// // The scene's own value, then another.
/// assert_eq!(renderer.param("materials.red.base_color")?.data, [0.63, 0.065, 0.05]);
/// renderer.set_param("materials.red.base_color", &[0.2, 0.9, 0.2])?;
/// let image = renderer.render(&RenderOptions { spp: 4, ..Default::default() })?;
/// assert_eq!((image.width, image.height), (64, 64));
/// // A brighter image everywhere: every channel's gradient is positive.
/// let adjoint = Image::filled(64, 64, [1.0; 3]);
/// let grads = renderer.gradient(&adjoint, &RenderOptions { spp: 4, seed: 1, ..Default::default() })?;
/// assert!(grads[0].1.data.iter().all(|&g| g > 0.0), "{grads:?}");
/// # Ok(())
/// # }
/// ```
pub struct Renderer {
    device: Device,
    scene: Scene,
    primal: PrimalRenderer,
    /// θ as the device holds it (the optimised parameters, in layout order).
    theta: Vec<f32>,
    gradients: RefCell<Option<Gradients>>,
    /// The adjoint pass that also sums half of the pixels, built on first use.
    split_gradients: RefCell<Option<Gradients>>,
}

impl Renderer {
    /// Uploads `scene` to `device`; its parameters start at the scene's own values.
    pub fn new(device: &Device, scene: &Scene) -> Result<Renderer> {
        let gs = GpuScene::configured(device.ctx(), scene, device.config())?;
        let primal = PrimalRenderer::new(gs)?;
        let theta = primal.scene.layout.reference();
        primal.scene.set_theta(theta.clone())?;
        let renderer =
            Renderer { device: device.clone(), scene: scene.clone(), primal, theta, gradients: RefCell::new(None), split_gradients: RefCell::new(None) };
        device.validated(renderer)
    }

    /// The scene, with every parameter at the value set here.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The optimised parameters, in the scene's order.
    pub fn params(&self) -> Vec<ParamInfo> {
        self.primal.scene.layout.slots.iter().map(|s| ParamInfo { name: s.name.clone(), shape: s.shape, range: s.range }).collect()
    }

    fn slot(&self, name: &str) -> Result<&crate::render::ParamSlot> {
        let layout = &self.primal.scene.layout;
        layout.named(name).ok_or_else(|| {
            let names: Vec<&str> = layout.slots.iter().map(|s| s.name.as_str()).collect();
            let known = if names.is_empty() { "none: the scene has no [[optimise.params]]".to_string() } else { names.join(", ") };
            Error::Invalid(format!("no parameter named '{name}' (the scene's parameters: {known})"))
        })
    }

    /// The value parameter `name` renders with.
    pub fn param(&self, name: &str) -> Result<ParamValue> {
        Ok(self.slot(name)?.value(&self.theta))
    }

    /// Sets parameter `name` to `values` (its shape's length, row-major with the channels
    /// innermost), clamped into its range. A wrong length or a value that is not finite is
    /// an error, and nothing changes.
    pub fn set_param(&mut self, name: &str, values: &[f32]) -> Result<()> {
        let slot = self.slot(name)?;
        if values.len() != slot.len {
            return Err(Error::Invalid(format!("{name}: {} values given, its shape {} has {}", values.len(), slot.shape, slot.len)));
        }
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return Err(Error::Invalid(format!("{name}: {v} is not a finite number")));
        }
        let [lo, hi] = slot.range;
        let (offset, shape, target) = (slot.offset, slot.shape, slot.target);
        let clamped: Vec<f32> = values.iter().map(|v| v.clamp(lo, hi)).collect();
        self.theta[offset..offset + clamped.len()].copy_from_slice(&clamped);
        self.primal.scene.set_theta(self.theta.clone())?;
        let value = ParamValue { shape, data: clamped };
        self.scene = crate::scene::write::apply(&self.scene, &[(target, value)]);
        self.device.validated(())
    }

    /// Renders a sensor: a linear RGB image of the film's size, rows from the top.
    pub fn render(&self, options: &RenderOptions) -> Result<Image> {
        Ok(self.render_until(options, |_, _| {}, || false)?.0)
    }

    /// [`Self::render`] in short submissions, calling `progress(done, total)` after each and
    /// asking `stop()` whether to end early: the image then holds the samples rendered so
    /// far (their mean), and the count is returned with it.
    pub fn render_until(&self, options: &RenderOptions, progress: impl FnMut(u32, u32), stop: impl Fn() -> bool) -> Result<(Image, u32)> {
        self.check(options)?;
        let rendered = self.primal.render_until(options.sensor, options.spp, gpu_seed(options.seed), progress, stop)?;
        self.device.validated(rendered)
    }

    fn check(&self, options: &RenderOptions) -> Result<()> {
        if options.spp == 0 {
            return Err(Error::Invalid("spp must be at least 1".into()));
        }
        let sensors = self.scene.sensors.len();
        if options.sensor as usize >= sensors {
            return Err(Error::Invalid(format!("sensor {}: the scene has {sensors} sensor(s)", options.sensor)));
        }
        Ok(())
    }

    /// The gradient passes, built on first use.
    /// The adjoint pass, built on first use; `split` the one that also sums half of the
    /// pixels.
    fn gradients(&self, split: bool) -> Result<std::cell::RefMut<'_, Gradients>> {
        let mut slot = if split { self.split_gradients.borrow_mut() } else { self.gradients.borrow_mut() };
        if slot.is_none() {
            let gs = &self.primal.scene;
            let ops = BufferOps::new(&gs.ctx)?;
            let zeroed = |name| crate::gpu::Buffer::zeroed::<f32>(&gs.ctx, name, gs.layout.len.max(1), MemoryKind::Device);
            let grad = zeroed("grad")?;
            let half = if split { Some(zeroed("grad half")?) } else { None };
            let blank: Vec<Image> = (0..gs.sensors).map(|_| Image::filled(gs.width, gs.height, [0.0; 3])).collect();
            let inputs = GradientInputs {
                targets: &blank,
                loss: Loss::L2,
                spp: 1,
                primal_spp: 1,
                seed: 0,
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: half.as_ref(),
            };
            let pass = GradientPass::new(gs, &ops, &inputs)?;
            *slot = Some(Gradients { pass, ops, half });
        }
        Ok(std::cell::RefMut::map(slot, |g| g.as_mut().expect("built above")))
    }

    fn check_image(&self, what: &str, image: &Image) -> Result<()> {
        let (w, h) = (self.scene.film.width, self.scene.film.height);
        if (image.width, image.height) != (w, h) || image.data.len() != (w * h) as usize {
            return Err(Error::Invalid(format!("{what}: {}x{} pixels, the film is {w}x{h}", image.width, image.height)));
        }
        if image.data.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::Invalid(format!("{what}: a value is not a finite number")));
        }
        Ok(())
    }

    /// Records and runs the passes `record` adds for the options' sensor, with their spp
    /// and seed, and reads the gradient back by parameter.
    /// Runs the adjoint pass of `adjoint` (written into sensor `options.sensor`'s adjoint
    /// image) and reads its gradient, and with `split` also the sum over half of the pixels.
    fn run_gradient(&self, adjoint: &Image, options: &RenderOptions, split: bool) -> Result<(Vec<(String, ParamValue)>, Option<Vec<(String, ParamValue)>>)> {
        self.check(options)?;
        self.check_image("the adjoint image", adjoint)?;
        let mut g = self.gradients(split)?;
        let sensor = options.sensor as usize;
        g.pass.adjoint_image(sensor).write(&adjoint.data)?;
        g.pass.spp = options.spp;
        g.pass.seed = gpu_seed(options.seed);
        let gs = &self.primal.scene;
        gs.set_frame(0)?;
        let g = &*g;
        let mut cmd = CommandBuffer::new(&gs.ctx, "gradient")?;
        cmd.record(|rec| {
            rec.zero(&g.pass.grad)?;
            if let Some(half) = &g.half {
                rec.zero(half)?;
            }
            g.pass.record_sensor_adjoint(rec, gs, &g.ops, sensor)
        })?;
        cmd.submit_and_wait()?;
        let read = |b: &crate::gpu::Buffer| -> Result<Vec<(String, ParamValue)>> {
            let mut v: Vec<f32> = b.read()?;
            v.truncate(gs.layout.len);
            self.device.validated(gs.layout.values(&v))
        };
        let half = match &g.half {
            Some(h) => Some(read(h)?),
            None => None,
        };
        Ok((read(&g.pass.grad)?, half))
    }

    /// The gradient of a loss L with respect to every parameter, given the loss's gradient
    /// with respect to the image, `adjoint` = dL/dImage (the film's size): path replay
    /// backpropagation of `adjoint` at `options.spp` samples per pixel with its own random
    /// numbers. Unbiased when `adjoint` does not depend on those numbers (compute it from a
    /// render with another seed).
    pub fn gradient(&self, adjoint: &Image, options: &RenderOptions) -> Result<Vec<(String, ParamValue)>> {
        Ok(self.run_gradient(adjoint, options, false)?.0)
    }

    /// [`Self::gradient`], and from the same pass the part of it that comes from a random
    /// half of the pixels (drawn from the seed): two independent halves of the estimate,
    /// whose difference estimates its variance, for the meta-estimator's centred variance
    /// (`var=centred`). Whole pixels, not samples: a pixel's samples share its adjoint.
    pub fn gradient_with_half(&self, adjoint: &Image, options: &RenderOptions) -> Result<(Vec<(String, ParamValue)>, Vec<(String, ParamValue)>)> {
        let (full, half) = self.run_gradient(adjoint, options, true)?;
        Ok((full, half.expect("the split pass sums a half")))
    }

    /// A built-in loss of a render against `target`, and its gradient with respect to every
    /// parameter: the loss of [`Self::render`] at `primal_spp` samples per pixel with
    /// `options`' sensor and seed, and [`Self::gradient`] of its adjoint with `options` (its
    /// own random numbers, so that the estimate is unbiased for L2).
    pub fn loss_gradient(&self, loss: Loss, target: &Image, primal_spp: u32, options: &RenderOptions) -> Result<(f64, Vec<(String, ParamValue)>)> {
        self.check_image("the target", target)?;
        let image = self.render(&RenderOptions { spp: primal_spp, ..*options })?;
        let (value, adjoint) = loss.evaluate(&image, target);
        Ok((value, self.gradient(&adjoint, options)?))
    }
}
