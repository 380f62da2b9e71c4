//! The native half of the Python package `vkinverse`: a scene on a device, its parameters,
//! renders, gradients and optimisation runs, over the library's API. Arrays cross as
//! little-endian float32 bytes with their shapes; `vkinverse/__init__.py` turns them into
//! numpy arrays (without a copy) and gives the package its Python shape.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use vkinverse::scene::{Film, LoadOptions, Texture};
use vkinverse::{Config, Device, Image, LogRow, Observer, RenderOptions, Renderer, RunOptions, Scene, Settings};

create_exception!(_native, Error, PyException, "An error of vkinverse other than bad input (a device, driver or file-system failure).");

/// The library's error as the binary words it: one line. Bad input is a `ValueError`.
fn error(e: vkinverse::Error) -> PyErr {
    let message = vkinverse::error::one_line(&e);
    match e {
        vkinverse::Error::Scene(_) | vkinverse::Error::Image(_) | vkinverse::Error::Npy(_) | vkinverse::Error::Optim(_) | vkinverse::Error::Invalid(_) => {
            PyValueError::new_err(message)
        }
        _ => Error::new_err(message),
    }
}

/// One device per choice (`None`: the best), opened once per process and shared.
fn device(choice: Option<String>) -> PyResult<Device> {
    static DEVICES: Mutex<Vec<(Option<String>, Device)>> = Mutex::new(Vec::new());
    let mut devices = DEVICES.lock().map_err(|_| Error::new_err("the device table is poisoned"))?;
    if let Some((_, d)) = devices.iter().find(|(c, _)| *c == choice) {
        return Ok(d.clone());
    }
    // The process's environment (VKINVERSE_VALIDATION, VKINVERSE_DEVICE, ...) as for the
    // binary; an explicit choice wins.
    let (mut config, _) = Config::from_env();
    if choice.is_some() {
        config.device = choice.clone();
    }
    let d = Device::new(&config).map_err(error)?;
    devices.push((choice, d.clone()));
    Ok(d)
}

/// Names of the Vulkan devices, in index order.
#[pyfunction]
fn devices() -> PyResult<Vec<String>> {
    Ok(device(None)?.devices().iter().map(|d| d.name.clone()).collect())
}

/// (name, float32 bytes, shape) of each parameter's value or gradient.
type Arrays<'py> = Vec<(String, Bound<'py, PyBytes>, Vec<usize>)>;

/// Named parameter values as (name, float32 bytes, shape) each.
fn arrays<'py>(py: Python<'py>, values: &[(String, vkinverse::ParamValue)]) -> Arrays<'py> {
    values.iter().map(|(name, v)| (name.clone(), floats(py, &v.data), v.shape.array())).collect()
}
/// (name, shape, (lo, hi)) of each parameter.
type ParamInfos = Vec<(String, Vec<usize>, (f32, f32))>;

fn floats<'py>(py: Python<'py>, data: &[f32]) -> Bound<'py, PyBytes> {
    PyBytes::new(py, bytemuck::cast_slice(data))
}

fn image_from_bytes(bytes: &[u8], height: u32, width: u32, what: &str) -> PyResult<Image> {
    let n = height as usize * width as usize;
    if bytes.len() != n * 12 {
        return Err(PyValueError::new_err(format!("{what}: {} bytes for {height} x {width} x 3 float32", bytes.len())));
    }
    let values = floats_of(bytes, what)?;
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!("{what}: {v} is not a finite number")));
    }
    Ok(Image { width, height, data: values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect() })
}

/// A scene loaded and uploaded to a device, with its optimised parameters.
#[pyclass(module = "vkinverse._native")]
struct NativeScene {
    /// Taken out while the GIL is released around GPU work.
    renderer: Mutex<Option<Renderer>>,
    device: Device,
    path: PathBuf,
}

impl NativeScene {
    /// Runs `f` on the renderer with the GIL released.
    fn with<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut Renderer) -> vkinverse::Result<T> + Send) -> PyResult<T> {
        let mut slot = self.renderer.lock().map_err(|_| Error::new_err("the scene is poisoned"))?;
        let mut renderer = slot.take().ok_or_else(|| Error::new_err("the scene is in use by another thread"))?;
        let (renderer, result) = py.allow_threads(move || {
            let r = f(&mut renderer);
            (renderer, r)
        });
        *slot = Some(renderer);
        result.map_err(error)
    }

    /// `f` of the renderer, with the GIL held (for what takes no GPU work).
    fn read<T>(&self, f: impl FnOnce(&Renderer) -> T) -> PyResult<T> {
        let slot = self.renderer.lock().map_err(|_| Error::new_err("the scene is poisoned"))?;
        Ok(f(slot.as_ref().ok_or_else(|| Error::new_err("the scene is in use by another thread"))?))
    }

    fn scene(&self) -> PyResult<Scene> {
        self.read(|r| r.scene().clone())
    }
}

#[pymethods]
impl NativeScene {
    #[new]
    #[pyo3(signature = (path, film=None, max_depth=None, device=None))]
    fn new(py: Python<'_>, path: PathBuf, film: Option<(u32, u32)>, max_depth: Option<u32>, device: Option<String>) -> PyResult<Self> {
        let dev = self::device(device)?;
        let options = LoadOptions { film: film.map(|(width, height)| Film { width, height }), max_depth };
        let d = dev.clone();
        let p = path.clone();
        let renderer = py.allow_threads(move || -> vkinverse::Result<Renderer> {
            let scene = Scene::load_with(&p, &options)?;
            Renderer::new(&d, &scene)
        });
        Ok(NativeScene { renderer: Mutex::new(Some(renderer.map_err(error)?)), device: dev, path })
    }

    /// (name, shape, (lo, hi)) of every optimised parameter, in the scene's order.
    fn param_info(&self) -> PyResult<ParamInfos> {
        self.read(|r| r.params().into_iter().map(|p| (p.name, p.shape.array(), (p.range[0], p.range[1]))).collect())
    }

    /// The value of parameter `name`: float32 bytes and its shape.
    fn get_param<'py>(&self, py: Python<'py>, name: &str) -> PyResult<(Bound<'py, PyBytes>, Vec<usize>)> {
        let v = self.read(|r| r.param(name))?.map_err(error)?;
        Ok((floats(py, &v.data), v.shape.array()))
    }

    /// Where an optimisation of parameter `name` starts (its `init`, float32 bytes) and its
    /// own learning rate, if the scene gives one.
    fn param_start<'py>(&self, py: Python<'py>, name: &str) -> PyResult<(Bound<'py, PyBytes>, Option<f32>)> {
        let start = self.read(|r| r.scene().optimise.params.iter().find(|p| p.name == name).map(|p| (p.init.clone(), p.lr)))?;
        let (init, lr) = start.ok_or_else(|| PyValueError::new_err(format!("no parameter named '{name}'")))?;
        Ok((floats(py, &init), lr))
    }

    /// Sets parameter `name` to float32 `values` (its length checked, clamped to its range).
    fn set_param(&self, py: Python<'_>, name: String, values: Vec<f32>) -> PyResult<()> {
        self.with(py, move |r| r.set_param(&name, &values))
    }

    /// Renders `sensor`: float32 bytes of [height, width, 3], and the height and width.
    fn render<'py>(&self, py: Python<'py>, spp: u32, seed: u64, sensor: u32) -> PyResult<(Bound<'py, PyBytes>, u32, u32)> {
        let options = RenderOptions { sensor, spp, seed };
        let image = self.with(py, move |r| r.render(&options))?;
        Ok((floats(py, image.data.as_flattened()), image.height, image.width))
    }

    /// Every parameter's gradient for the image-space adjoint dL/dImage (float32 bytes of
    /// [height, width, 3]): (name, float32 bytes, shape) each.
    #[allow(clippy::too_many_arguments)]
    fn gradient<'py>(&self, py: Python<'py>, adjoint: &[u8], height: u32, width: u32, spp: u32, seed: u64, sensor: u32) -> PyResult<Arrays<'py>> {
        let adjoint = image_from_bytes(adjoint, height, width, "adjoint")?;
        let options = RenderOptions { sensor, spp, seed };
        let grads = self.with(py, move |r| r.gradient(&adjoint, &options))?;
        Ok(arrays(py, &grads))
    }

    /// `gradient`, and from the same pass the sum over a random half of the pixels (drawn
    /// from the seed): (full, half), each as `gradient` returns it.
    #[allow(clippy::too_many_arguments)]
    fn gradient_with_half<'py>(
        &self,
        py: Python<'py>,
        adjoint: &[u8],
        height: u32,
        width: u32,
        spp: u32,
        seed: u64,
        sensor: u32,
    ) -> PyResult<(Arrays<'py>, Arrays<'py>)> {
        let adjoint = image_from_bytes(adjoint, height, width, "adjoint")?;
        let options = RenderOptions { sensor, spp, seed };
        let (full, half) = self.with(py, move |r| r.gradient_with_half(&adjoint, &options))?;
        Ok((arrays(py, &full), arrays(py, &half)))
    }

    /// The film's (width, height), the number of sensors, and the warnings of loading.
    fn film(&self) -> PyResult<(u32, u32)> {
        self.read(|r| (r.scene().film.width, r.scene().film.height))
    }

    fn sensor_count(&self) -> PyResult<usize> {
        self.read(|r| r.scene().sensors.len())
    }

    fn warnings(&self) -> PyResult<Vec<String>> {
        self.read(|r| r.scene().warnings.iter().cloned().chain(r.scene().render_warnings()).collect())
    }

    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// An optimisation run of the scene as its parameters stand: `settings` are the command
    /// line's (key, value text) pairs, `targets` one float32 image per sensor (bytes,
    /// height, width), `callback(row)` hears each iteration (False stops the run) and
    /// `progress(done, total)` each one; Ctrl-C stops it after an iteration and raises
    /// KeyboardInterrupt. Returns (params: [(name, bytes, shape)], log: {column: [values]},
    /// interrupted).
    #[pyo3(signature = (settings, targets=None, callback=None, out_dir=None, resume=false, overwrite=false))]
    #[allow(clippy::too_many_arguments)]
    fn optimise<'py>(
        &self,
        py: Python<'py>,
        settings: Vec<(String, String)>,
        targets: Option<Vec<(Vec<u8>, u32, u32)>>,
        callback: Option<PyObject>,
        out_dir: Option<PathBuf>,
        resume: bool,
        overwrite: bool,
    ) -> PyResult<(Arrays<'py>, Bound<'py, PyDict>, bool)> {
        let bad = |e: vkinverse::settings::Invalid| PyValueError::new_err(format!("{}: {}", e.key, e.message));
        let mut layer = Settings::default();
        for (key, value) in &settings {
            layer.set(key, value).map_err(bad)?;
        }
        layer.validate().map_err(bad)?;
        let mut scene = self.scene()?;
        if let Some(targets) = targets {
            if targets.len() != scene.sensors.len() {
                return Err(PyValueError::new_err(format!("{} target images for {} sensors", targets.len(), scene.sensors.len())));
            }
            for (i, (bytes, h, w)) in targets.iter().enumerate() {
                let image = image_from_bytes(bytes, *h, *w, &format!("targets[{i}]"))?;
                if (w, h) != (&scene.film.width, &scene.film.height) {
                    return Err(PyValueError::new_err(format!("targets[{i}]: {h} x {w}, the film is {} x {}", scene.film.height, scene.film.width)));
                }
                scene.sensors[i].target_image = Some(Texture::new(PathBuf::from(format!("<targets[{i}]>")), Arc::new(image)));
            }
        }
        let run_settings = layer.resolve_for(&scene);
        let mode = match (resume, overwrite) {
            (true, _) => vkinverse::Mode::Resume,
            (false, true) => vkinverse::Mode::Overwrite,
            _ => vkinverse::Mode::New,
        };
        let options = RunOptions { out_dir: out_dir.as_deref(), mode, cancel: vkinverse::Cancel::new() };
        let mut observer = PyObserver { callback, error: None, cancel: options.cancel.clone() };
        let device = self.device.clone();
        // The GIL is released during the run; the observer takes it for each iteration's
        // callback (and checks for Ctrl-C there).
        let outcome = py.allow_threads(|| vkinverse::optimise(&device, &scene, &run_settings, &options, &mut observer));
        if let Some(e) = observer.error.take() {
            return Err(e);
        }
        let run = outcome.map_err(error)?.into_run();
        let log = PyDict::new(py);
        let rows = &run.log.rows;
        log.set_item("iteration", rows.iter().map(|r| r.iteration).collect::<Vec<_>>())?;
        log.set_item("time_s", rows.iter().map(|r| r.time_s).collect::<Vec<_>>())?;
        log.set_item("gpu_time_s", rows.iter().map(|r| r.gpu_time_s).collect::<Vec<_>>())?;
        log.set_item("loss", rows.iter().map(|r| r.loss.unwrap_or(f64::NAN)).collect::<Vec<_>>())?;
        log.set_item("param_error", rows.iter().map(|r| r.param_error.unwrap_or(f64::NAN)).collect::<Vec<_>>())?;
        for (k, name) in run.log.params.iter().enumerate() {
            let column: Vec<f64> = rows.iter().map(|r| r.param_errors.get(k).copied().flatten().unwrap_or(f64::NAN)).collect();
            log.set_item(format!("param_error.{name}"), column)?;
        }
        let params = arrays(py, &run.params);
        Ok((params, log, run.summary.interrupted))
    }
}

/// float32 values from little-endian bytes.
fn floats_of(bytes: &[u8], what: &str) -> PyResult<Vec<f32>> {
    if !bytes.len().is_multiple_of(4) {
        return Err(PyValueError::new_err(format!("{what}: {} bytes are not float32 values", bytes.len())));
    }
    Ok(bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
}

/// The library's optimiser on host arrays (`vkinverse::HostOptimiser`): a spec over
/// parameter groups (len, lr, lo, hi) laid one after the other in a flat float32 buffer.
#[pyclass(module = "vkinverse._native")]
struct HostOptimiser {
    inner: vkinverse::HostOptimiser,
}

#[pymethods]
impl HostOptimiser {
    #[new]
    #[pyo3(signature = (spec, groups, iterations=None))]
    fn new(spec: &str, groups: Vec<(usize, f64, f64, f64)>, iterations: Option<u32>) -> PyResult<Self> {
        let groups: Vec<vkinverse::HostGroup> =
            groups.into_iter().map(|(len, lr, lo, hi)| vkinverse::HostGroup { len, lr, range: vkinverse::replay::Range { lo, hi } }).collect();
        let inner = vkinverse::HostOptimiser::new(spec, &groups, iterations).map_err(|e| error(e.into()))?;
        Ok(HostOptimiser { inner })
    }

    /// The optimiser's name: `adam` or `meta`.
    fn kind(&self) -> &'static str {
        self.inner.optimiser().name()
    }

    /// Whether a step needs the finite-difference sample (meta).
    fn needs_fd(&self) -> bool {
        self.inner.optimiser().needs_fd()
    }

    /// Whether a step needs the half-sample sums of both streams (meta with `var=centred`).
    fn needs_halves(&self) -> bool {
        self.inner.optimiser().needs_halves()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// One step: θ, the gradient and (meta) the finite-difference sample and (centred) the
    /// half-sample sums, each float32 bytes of the buffer's length. Returns (θ' as float32
    /// bytes, the number of elements skipped for a non-finite input).
    #[pyo3(signature = (theta, grad, fd=None, grad_half=None, fd_half=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        theta: &[u8],
        grad: &[u8],
        fd: Option<&[u8]>,
        grad_half: Option<&[u8]>,
        fd_half: Option<&[u8]>,
    ) -> PyResult<(Bound<'py, PyBytes>, u64)> {
        let mut theta = floats_of(theta, "theta")?;
        let grad = floats_of(grad, "grad")?;
        let fd = fd.map(|b| floats_of(b, "fd")).transpose()?;
        let grad_half = grad_half.map(|b| floats_of(b, "grad_half")).transpose()?;
        let fd_half = fd_half.map(|b| floats_of(b, "fd_half")).transpose()?;
        let input = vkinverse::HostStep { grad: &grad, fd: fd.as_deref(), grad_half: grad_half.as_deref(), fd_half: fd_half.as_deref() };
        let skipped = self.inner.step(&mut theta, input).map_err(|e| error(e.into()))?;
        Ok((floats(py, &theta), skipped))
    }

    /// The last step's diagnostics, one {column: value} per group (the columns of
    /// optimiser.csv).
    fn diagnostics(&self) -> Vec<Vec<(&'static str, f64)>> {
        self.inner.diagnostics().iter().map(|d| vkinverse::Diagnostics::COLUMNS.iter().copied().zip(d.values()).collect()).collect()
    }
}

/// The run's observer: each log row to the Python callback, Ctrl-C between iterations.
struct PyObserver {
    callback: Option<PyObject>,
    /// The first Python exception (the callback's, or KeyboardInterrupt), raised after the
    /// run has stopped and written its outputs.
    error: Option<PyErr>,
    cancel: vkinverse::Cancel,
}

impl Observer for PyObserver {
    fn iteration(&mut self, row: &LogRow, _diagnostics: &[vkinverse::Diagnostics]) -> ControlFlow<()> {
        Python::with_gil(|py| {
            if let Err(e) = py.check_signals() {
                if e.is_instance_of::<PyKeyboardInterrupt>(py) {
                    self.cancel.cancel();
                }
                self.error = Some(e);
                return ControlFlow::Break(());
            }
            let Some(callback) = &self.callback else { return ControlFlow::Continue(()) };
            let dict = PyDict::new(py);
            let set = |k: &str, v: PyObject| dict.set_item(k, v);
            let result = (|| -> PyResult<bool> {
                set("iteration", row.iteration.into_pyobject(py)?.into_any().unbind())?;
                set("time_s", row.time_s.into_pyobject(py)?.into_any().unbind())?;
                set("gpu_time_s", row.gpu_time_s.into_pyobject(py)?.into_any().unbind())?;
                set("loss", row.loss.unwrap_or(f64::NAN).into_pyobject(py)?.into_any().unbind())?;
                set("param_error", row.param_error.unwrap_or(f64::NAN).into_pyobject(py)?.into_any().unbind())?;
                let answer = callback.call1(py, (dict.clone(),))?;
                // Only an explicit False stops: a callback that returns nothing continues.
                Ok(!answer.bind(py).is(pyo3::types::PyBool::new(py, false)))
            })();
            match result {
                Ok(true) => ControlFlow::Continue(()),
                Ok(false) => ControlFlow::Break(()),
                Err(e) => {
                    self.error = Some(e);
                    ControlFlow::Break(())
                }
            }
        })
    }

    fn warning(&mut self, message: &str) {
        Python::with_gil(|py| {
            let warnings = py.import("warnings").and_then(|w| w.call_method1("warn", (message.to_string(),)));
            if let Err(e) = warnings {
                self.error.get_or_insert(e);
            }
        });
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(devices, m)?)?;
    m.add_class::<NativeScene>()?;
    m.add_class::<HostOptimiser>()?;
    m.add("Error", m.py().get_type::<Error>())?;
    Ok(())
}
