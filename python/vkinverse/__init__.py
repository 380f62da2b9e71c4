"""vkinverse: inverse path tracing on any Vulkan device.

Load a scene (TOML, glTF/GLB or Mitsuba XML), render it, differentiate any image loss
with respect to its optimised parameters, and recover them from target images with Adam
or the gradient meta-estimator::

    import vkinverse as vk
    scene = vk.Scene("scenes/cornell/scene.toml")
    image = vk.render(scene, spp=64)                  # float32 [H, W, 3]
    grads = vk.gradient(scene, 2 * (image - target))  # {name: array shaped like the parameter}
    result = vk.optimise(scene, iterations=100)       # result.params, result.log

Parameters are named by the targets of the scene's ``[[optimise.params]]``
(``materials.red.base_color``). Errors are ``ValueError`` for bad input and
:class:`vkinverse.Error` for the rest, with the command line's one-line messages.
"""

import os
import sys
from collections.abc import MutableMapping

import numpy as np

from . import _native
from ._native import Error

__all__ = ["Error", "HostOptimiser", "ParameterError", "Result", "Scene", "devices", "gradient", "optimise", "render"]


class ParameterError(KeyError, ValueError):
    """A parameter name that the scene does not have (a KeyError of ``scene.params``, and a
    ValueError as all bad input is)."""

    def __str__(self):
        return str(self.args[0]) if self.args else ""


def devices():
    """Names of the Vulkan devices, in index order (``device=`` takes an index or part of a
    name)."""
    return _native.devices()


def _array(data, shape):
    """A read-only float32 view of native bytes (no copy)."""
    a = np.frombuffer(data, dtype=np.float32).reshape(shape)
    a.flags.writeable = False
    return a


def _floats(value, what):
    a = np.ascontiguousarray(value, dtype=np.float32)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: holds a value that is not a finite number")
    return a


class Params(MutableMapping):
    """The scene's optimised parameters: name -> float32 array (a colour is shape (3,), a
    texture (H, W, C)). Setting one checks its shape and clamps it into its range."""

    def __init__(self, native):
        self._native = native

    def _info(self):
        return {name: (tuple(shape), rng) for name, shape, rng in self._native.param_info()}

    def _unknown(self, name, info):
        known = ", ".join(info) or "none: the scene has no [[optimise.params]]"
        return ParameterError(f"no parameter named '{name}' (the scene's parameters: {known})")

    def __getitem__(self, name):
        info = self._info()
        if name not in info:
            raise self._unknown(name, info)
        data, shape = self._native.get_param(name)
        return _array(data, shape)

    def __setitem__(self, name, value):
        info = self._info()
        if name not in info:
            raise self._unknown(name, info)
        a = _floats(value, name)
        if a.shape != info[name][0]:
            raise ValueError(f"{name}: shape {a.shape} given, the parameter's is {info[name][0]}")
        self._native.set_param(name, a.ravel().tolist())

    def __delitem__(self, name):
        raise TypeError("a scene's parameters cannot be removed")

    def __iter__(self):
        return iter(self._info())

    def __len__(self):
        return len(self._native.param_info())

    def shape(self, name):
        """The parameter's array shape."""
        return self._info()[name][0]

    def range(self, name):
        """The parameter's (lo, hi): values set are clamped into it."""
        return self._info()[name][1]

    def __repr__(self):
        return "Params(" + ", ".join(f"{n}: {s}" for n, (s, _) in self._info().items()) + ")"


class Scene:
    """A scene loaded from ``path`` (.toml, .gltf/.glb or .xml) and uploaded to a device.

    ``film=(width, height)`` and ``max_depth`` override the file's; ``device`` is an index
    or part of a device's name (default: the best device). ``scene.params`` reads and sets
    the values it renders with."""

    def __init__(self, path, film=None, max_depth=None, device=None):
        if film is not None:
            film = (int(film[0]), int(film[1]))
        self._native = _native.NativeScene(os.fspath(path), film, max_depth, None if device is None else str(device))
        self.params = Params(self._native)

    @property
    def film(self):
        """(width, height) of the images it renders."""
        return self._native.film()

    @property
    def sensors(self):
        """The number of sensors (cameras)."""
        return self._native.sensor_count()

    @property
    def warnings(self):
        """What loading approximated and what the scene will not get, one line each."""
        return self._native.warnings()

    @property
    def path(self):
        return self._native.path()

    def __repr__(self):
        w, h = self.film
        return f"Scene({str(self.path)!r}, film={w}x{h}, params={list(self.params)})"


def render(scene, spp=64, seed=0, sensor=0):
    """Renders a sensor: float32 array [height, width, 3] of linear RGB. The same seed and
    spp give the same image."""
    data, h, w = scene._native.render(int(spp), int(seed), int(sensor))
    return _array(data, (h, w, 3))


def gradient(scene, adjoint, spp=16, seed=0, sensor=0):
    """Every parameter's gradient for the image-space adjoint ``adjoint`` = dL/dImage
    (float32 [height, width, 3]): {name: array shaped like the parameter}."""
    grads = scene._native.gradient(*_adjoint(scene, adjoint, "adjoint"), int(spp), int(seed), int(sensor))
    return _named(grads)


def _adjoint(scene, adjoint, what):
    """An adjoint image as the native calls take it: (float32 bytes, height, width), its
    shape checked against the film."""
    w, h = scene.film
    a = _floats(adjoint, what)
    if a.shape != (h, w, 3):
        raise ValueError(f"{what}: shape {a.shape}, the film's image is {(h, w, 3)}")
    return a.tobytes(), h, w


def _named(arrays):
    """{name: array} of native (name, bytes, shape) triples."""
    return {name: _array(data, shape) for name, data, shape in arrays}


class Result:
    """An optimisation's outcome: ``params`` {name: final array}, ``log`` {column: numpy
    array} (the columns of log.csv: iteration, time_s, gpu_time_s, loss, param_error and
    one param_error.NAME per parameter), ``interrupted`` (stopped by the callback or
    Ctrl-C) and ``out_dir``."""

    def __init__(self, params, log, interrupted, out_dir):
        self.params = params
        self.log = log
        self.interrupted = interrupted
        self.out_dir = out_dir

    def __repr__(self):
        n = len(self.log.get("iteration", []))
        return f"Result(params={list(self.params)}, rows={n}, interrupted={self.interrupted})"


class _Progress:
    """One line of progress on stderr (tqdm's bar where it is installed)."""

    def __init__(self, total, quiet):
        self.total, self.quiet, self.bar = total, quiet, None
        if not quiet:
            try:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=total, unit="it")
            except ImportError:
                pass

    def update(self, row):
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(loss=row.get("loss"))
        else:
            total = f"/{self.total}" if self.total else ""
            line = f"iteration {row['iteration']}{total}  loss {row.get('loss', float('nan')):.4g}"
            if sys.stderr.isatty():
                print("\r" + line, end="", file=sys.stderr)
            elif row["iteration"] % max(1, (self.total or 100) // 10) == 0:
                print(line, file=sys.stderr)

    def close(self):
        if self.bar is not None:
            self.bar.close()
        elif not self.quiet and sys.stderr.isatty():
            print(file=sys.stderr)


def _setting_text(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def optimise(scene, optimiser="meta", iterations=200, loss="l2", targets=None, callback=None, out_dir=None, quiet=False, resume=False, overwrite=False, **settings):
    """Recovers the scene's optimised parameters from target images.

    - ``optimiser``: a spec, ``meta``, ``meta-seed`` or ``adam`` with hyperparameters (``adam@beta1=0.5``).
    - ``loss``: ``l2``, ``l1`` or ``relative_l2``, or a Python function ``image ->
      (value, dL/dimage)``. A Python loss runs with ``adam`` (one call per iteration, on
      that iteration's primal render) or the meta-estimator (``meta``, ``meta-seed``: 3
      calls per iteration, 1 at the first: the primal render of θ_i, then the two renders of
      θ_i and θ_{i-1} with one seed whose gradients' difference is the finite-difference
      sample). The meta-estimator's carried primal image needs a built-in loss: with a
      Python loss meta runs with ``carry=0`` (``meta`` is ``meta@carry=0``), and a spec that
      sets ``carry`` above 0 is a ValueError. A Python-loss run takes the settings ``lr``,
      ``spp``, ``primal_spp``, ``seed`` (adam also ``beta1``, ``beta2``; meta ``fd_spp``),
      no ``targets`` and no ``out_dir``; its log has the columns iteration, time_s and
      loss.
    - ``targets``: one float32 [H, W, 3] image per sensor; without them the targets are
      rendered from the scene's own values, as the command line does.
    - ``callback(row)``: each iteration's log row as a dict; returning False stops the run.
    - ``out_dir``: a run directory (checkpoints, log.csv, params/, plots, preview.png:
      target | start | final | difference), resumable with ``resume=True``.
    - ``**settings``: any setting of ``vkinverse optimise`` by its name (``spp``,
      ``primal_spp``, ``fd_spp``, ``lr``, ``time_budget``, ``seed``, ...).

    The run starts from each parameter's ``init``. Ctrl-C stops it after the current
    iteration (its outputs written) and raises KeyboardInterrupt."""
    if callable(loss):
        return _optimise_python_loss(scene, loss, optimiser, iterations, targets, callback, out_dir, quiet, settings)
    pairs = [("optimiser", str(optimiser)), ("loss", str(loss))]
    if iterations is not None:
        pairs.append(("iterations", str(int(iterations))))
    pairs += [(k, _setting_text(v)) for k, v in settings.items()]
    native_targets = None
    if targets is not None:
        if isinstance(targets, np.ndarray):
            targets = [targets]
        native_targets = []
        for i, t in enumerate(targets):
            a = _floats(t, f"targets[{i}]")
            if a.ndim != 3 or a.shape[2] != 3:
                raise ValueError(f"targets[{i}]: shape {a.shape}, expected [height, width, 3]")
            native_targets.append((a.tobytes(), a.shape[0], a.shape[1]))
    progress = _Progress(iterations, quiet)

    def hear(row):
        progress.update(row)
        if callback is not None:
            return callback(row)
        return True

    try:
        params, log, interrupted = scene._native.optimise(pairs, native_targets, hear, None if out_dir is None else os.fspath(out_dir), resume, overwrite)
    finally:
        progress.close()
    return Result({n: _array(d, s) for n, d, s in params}, {k: np.asarray(v) for k, v in log.items()}, interrupted, out_dir)


def _python_loss_settings(settings, allowed):
    unknown = set(settings) - set(allowed)
    if unknown:
        raise ValueError(f"{sorted(unknown)}: not settings of a Python-loss run ({', '.join(allowed)})")


def _start(scene, settings):
    """Each parameter's start value (its ``init``, set on the scene), learning rate (the
    ``lr`` setting, else the scene's rate for it, else 0.02) and range, in the scene's
    order."""
    names = list(scene.params)
    theta, lrs, ranges = {}, {}, {}
    for n in names:
        init, lr = scene._native.param_start(n)
        theta[n] = np.frombuffer(init, dtype=np.float32).reshape(scene.params.shape(n)).copy()
        lrs[n] = float(settings.get("lr", lr if lr is not None else 0.02))
        ranges[n] = scene.params.range(n)
        scene.params[n] = theta[n]
    return names, theta, lrs, ranges


class HostOptimiser:
    """The library's optimiser passes on the host (the f64 reference that the GPU passes
    are checked against), for a loop that produces the gradients itself: ``spec`` as
    ``optimise`` takes it, over parameter groups ``[(length, lr, lo, hi), ...]`` laid one
    after the other in one flat float32 vector. ``iterations`` is the horizon of a cosine
    schedule that gives none.

    ``step(theta, grad, fd=None, grad_half=None, fd_half=None)`` returns the new θ: ``grad``
    is the gradient estimate ⟨F_i⟩; the meta-estimator also takes the finite-difference
    sample ⟨ΔF_i⟩ = g(θ_i) − g(θ_{i−1}) with common random numbers (unused at the first
    step), and with ``var=centred`` (the ``meta`` default) the sums of half of the samples
    of each. ``diagnostics()`` are the last step's, one dict per group (the columns of
    optimiser.csv)."""

    def __init__(self, spec, groups, iterations=None):
        groups = [(int(n), float(lr), float(lo), float(hi)) for n, lr, lo, hi in groups]
        self._native = _native.HostOptimiser(str(spec), groups, None if iterations is None else int(iterations))
        self.kind = self._native.kind()
        self.needs_fd = self._native.needs_fd()
        self.needs_halves = self._native.needs_halves()
        self.skipped = 0

    def __len__(self):
        return len(self._native)

    def step(self, theta, grad, fd=None, grad_half=None, fd_half=None):
        def raw(a):
            return None if a is None else np.ascontiguousarray(a, dtype=np.float32).ravel().tobytes()

        data, skipped = self._native.step(raw(theta), raw(grad), raw(fd), raw(grad_half), raw(fd_half))
        self.skipped += skipped
        return np.frombuffer(data, dtype=np.float32).copy()

    def diagnostics(self):
        return [dict(d) for d in self._native.diagnostics()]


def _explicit_carry(spec):
    """The value of ``carry`` where the spec text sets it (``meta@carry=0.1``), else None."""
    for item in spec.split("@")[1:]:
        key, _, value = item.partition("=")
        if key.strip() == "carry":
            return float(value)
    return None


def _flat(arrays, names):
    return np.concatenate([np.asarray(arrays[n], dtype=np.float32).ravel() for n in names])


def _positional_arity(fn):
    """How many positional arguments `fn` takes (a large number for *args; 1 where its
    signature cannot be read)."""
    import inspect

    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return 1
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return 1 << 30
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


def _optimise_python_loss(scene, loss_fn, optimiser, iterations, targets, callback, out_dir, quiet, settings):
    """A run on a Python loss, stepped by the library's optimiser passes on the host
    (``HostOptimiser``; each parameter one group). Per iteration i (seeds derived from
    ``seed`` and i):

    1. the primal image of θ_i (``primal_spp``) -> loss -> adjoint;
    2. ⟨F_i⟩ = gradient(θ_i, adjoint, ``spp``), and with ``var=centred`` from the same pass
       its part from a random half of the pixels (the half-sample sum);
    3. the meta-estimator, from i = 2: ⟨ΔF_i⟩ with common random numbers: θ_i and θ_{i−1}
       rendered with one seed at ``fd_spp`` -> loss on each -> adjoints; gradient(θ_i, its
       adjoint) − gradient(θ_{i−1}, its adjoint), both with that seed (for ``var=centred``
       with their parts from one half of the pixels, the same for both: it is drawn from
       the seed). The first step has no θ_{i−1}: ⟨ΔF_1⟩ = 0,
       as in the engine, whose optimiser skips the ΔF terms on a step that follows no step;
    4. the step, clamped to the ranges.

    The loss is called once per iteration with Adam, 3 times with the meta-estimator (once
    at the first); with several sensors, that many times per sensor, as ``fn(image,
    sensor)``, and the values and gradients of the sensors add up. The carried primal image (``carry``) needs the engine's own loss: here
    the losses read each iteration's own renders (``carry=0``), and a spec that sets
    ``carry`` above 0 is refused."""
    if targets is not None:
        raise ValueError("targets: a Python loss holds its own targets")
    if out_dir is not None:
        raise ValueError("out_dir: a Python-loss run writes no run directory (its parameters and log are returned in the Result)")
    spec = str(optimiser)
    is_adam = spec.split("@")[0] == "adam"
    _python_loss_settings(settings, ["lr", "spp", "primal_spp", "seed"] + (["beta1", "beta2"] if is_adam else ["fd_spp"]))
    # Adam's decays given as settings join its spec.
    spec += "".join(f"@{k}={float(settings[k])}" for k in ("beta1", "beta2") if k in settings)
    spp, primal_spp, fd_spp = int(settings.get("spp", 2)), int(settings.get("primal_spp", 4)), int(settings.get("fd_spp", 1))
    seed = int(settings.get("seed", 0))
    names = list(scene.params)
    if not names:
        raise ValueError("the scene has no [[optimise.params]]: nothing to optimise")
    # The spec is parsed (and refused with the library's message) before anything renders.
    shapes = {n: scene.params.shape(n) for n in names}
    probe = HostOptimiser(spec, [(int(np.prod(shapes[n], dtype=np.int64)), 0.0, *scene.params.range(n)) for n in names])
    if probe.kind not in ("adam", "meta"):
        raise ValueError(f"optimiser {spec!r}: a Python loss runs with adam, meta or meta-seed")
    carry = _explicit_carry(spec)
    if carry is not None and carry > 0:
        raise ValueError(f"optimiser {spec!r}: carry = {carry}: the carried primal image needs a built-in loss (a Python loss runs meta with carry=0)")
    sensors = scene.sensors
    if sensors > 1 and _positional_arity(loss_fn) < 2:
        raise ValueError(f"loss: the scene has {sensors} sensors: a Python loss is then called as fn(image, sensor), for each sensor")

    def loss_of(image, k):
        return loss_fn(image) if sensors == 1 else loss_fn(image, k)

    names, theta, lrs, ranges = _start(scene, settings)
    opt = HostOptimiser(spec, [(theta[n].size, lrs[n], *ranges[n]) for n in names], iterations)
    sizes = [theta[n].size for n in names]
    x = _flat(theta, names)
    x_prev = None
    log = {"iteration": [], "time_s": [], "loss": []}
    progress = _Progress(iterations, quiet)
    import time

    def set_all(values):
        for n, part in zip(names, np.split(values, np.cumsum(sizes)[:-1])):
            scene.params[n] = part.reshape(shapes[n])

    def grad_at(adjoint, spp_, seed_, halves, k):
        """The flat gradient of `adjoint` (of sensor k) and, with `halves`, its part from a
        random half of the pixels (drawn from the seed), from the same pass."""
        a = _adjoint(scene, adjoint, "the loss's dL/dimage")
        if not halves:
            return _flat(_named(scene._native.gradient(*a, int(spp_), int(seed_), int(k))), names), None
        full, half = scene._native.gradient_with_half(*a, int(spp_), int(seed_), int(k))
        return _flat(_named(full), names), _flat(_named(half), names)

    def loss_gradient(spp_, seed_, halves):
        """The loss of every sensor's render (render and gradient passes with one seed) and
        the flat gradient of the sum, with its half-pixel part."""
        value, total, total_half = 0.0, None, None
        for k in range(sensors):
            v, adjoint = loss_of(render(scene, spp=spp_, seed=seed_, sensor=k), k)
            g, g_half = grad_at(adjoint, spp_, seed_, halves, k)
            value += float(v)
            total = g if total is None else total + g
            if halves:
                total_half = g_half if total_half is None else total_half + g_half
        return value, total, total_half

    start, interrupted = time.perf_counter(), False
    try:
        for it in range(1, int(iterations) + 1):
            base = 4 * (seed * 1000003 + it)
            halves = opt.needs_halves
            set_all(x)
            value, f, f_half = 0.0, None, None
            for k in range(sensors):
                v, adjoint = loss_of(render(scene, spp=primal_spp, seed=base, sensor=k), k)
                g, g_half = grad_at(adjoint, spp, base + 1, halves, k)
                value += float(v)
                f = g if f is None else f + g
                if halves:
                    f_half = g_half if f_half is None else f_half + g_half
            fd = fd_half = None
            if opt.needs_fd and x_prev is None:
                fd = np.zeros_like(f)
                fd_half = np.zeros_like(f) if halves else None
            elif opt.needs_fd:
                _, at_cur, at_cur_half = loss_gradient(fd_spp, base + 2, halves)
                set_all(x_prev)
                _, at_prev, at_prev_half = loss_gradient(fd_spp, base + 2, halves)
                fd = at_cur - at_prev
                fd_half = at_cur_half - at_prev_half if halves else None
            x_prev = x
            x = opt.step(x, f, fd, f_half, fd_half)
            set_all(x)
            row = {"iteration": it, "time_s": time.perf_counter() - start, "loss": float(value)}
            for k in log:
                log[k].append(row[k])
            progress.update(row)
            if callback is not None and callback(row) is False:
                interrupted = True
                break
    finally:
        progress.close()
    params = {n: part.reshape(shapes[n]) for n, part in zip(names, np.split(x, np.cumsum(sizes)[:-1]))}
    return Result(params, {k: np.asarray(c) for k, c in log.items()}, interrupted, None)


