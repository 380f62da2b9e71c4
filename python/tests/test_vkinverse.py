"""The Python package on the machine's Vulkan device (lavapipe in CI): renders against the
command line's, gradients against finite differences, the autograd wrappers, optimisation
runs (built-in and Python losses, stopped and resumed) and bad input.

Run from the repository root: python3 -m pytest python/tests (or python3 -m unittest
discover -s python/tests). The JAX and PyTorch tests need those packages; where one is
missing its tests are reported as skipped, never as passed.
"""

import os
import shutil
import signal
import subprocess
import tempfile
import unittest
from pathlib import Path

import numpy as np

import vkinverse as vk

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell" / "scene.toml"
RED = "materials.red.base_color"


def binary():
    """The command line's binary, built by cargo for the test run."""
    for profile in ["debug", "release"]:
        exe = ROOT / "target" / profile / "vkinverse"
        if exe.exists():
            return exe
    raise unittest.SkipTest("no target/*/vkinverse: build the binary first (cargo build)")


def cornell(film=(32, 32)):
    return vk.Scene(CORNELL, film=film)


def fd_of_mean(scene, name, channel, h=0.05, spp=256, seed=7):
    """d mean(image) / d value[channel], by central differences of two renders with the
    same seed (their noise mostly cancels)."""
    base = np.array(scene.params[name])
    values = []
    for sign in (1, -1):
        v = base.copy()
        v[channel] += sign * h
        scene.params[name] = v
        values.append(float(np.mean(vk.render(scene, spp=spp, seed=seed))))
    scene.params[name] = base
    return (values[0] - values[1]) / (2 * h)


def check_wrapper_gradient(scene, g):
    """A wrapper's gradient of mean(render(spp=16, seed=5, grad_spp=64)) with respect to the
    red wall: vkinverse's own estimate for the same adjoint and seed (seed + 1), and within
    the noise of finite differences."""
    w, h = scene.film
    direct = vk.gradient(scene, np.full((h, w, 3), 1.0 / (w * h * 3), np.float32), spp=64, seed=6)[RED]
    np.testing.assert_allclose(g, direct, rtol=1e-5, atol=1e-7)
    fd = [fd_of_mean(scene, RED, c) for c in range(3)]
    np.testing.assert_allclose(g, fd, rtol=0.25, atol=2e-3)


class RenderTests(unittest.TestCase):
    def test_render_equals_the_command_line_value_for_value(self):
        scene = vk.Scene(CORNELL)
        image = vk.render(scene, spp=4, seed=3)
        self.assertEqual(image.shape, (64, 64, 3))
        self.assertEqual(image.dtype, np.float32)
        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "cli.npy"
            subprocess.run([binary(), "render", CORNELL, "--spp", "4", "--seed", "3", "-o", out, "--quiet"], check=True)
            cli = np.load(out)
        np.testing.assert_array_equal(image, cli)

    def test_params_read_set_clamp_and_render_differently(self):
        scene = cornell()
        self.assertEqual(list(scene.params), [RED])
        np.testing.assert_allclose(scene.params[RED], [0.63, 0.065, 0.05], rtol=1e-6)
        before = vk.render(scene, spp=4)
        scene.params[RED] = np.array([5.0, 0.9, -1.0])  # clamped into [0, 1]
        lo, hi = scene.params.range(RED)
        np.testing.assert_allclose(scene.params[RED], [hi, 0.9, lo])
        after = vk.render(scene, spp=4)
        self.assertGreater(np.abs(after - before).max(), 0.01)
        self.assertFalse(scene.params[RED].flags.writeable, "a read-only view, not a copy to write into")

    def test_bad_input_raises_with_the_one_line_message(self):
        scene = cornell()
        with self.assertRaisesRegex(ValueError, r"shape \(2,\) given, the parameter's is \(3,\)"):
            scene.params[RED] = [0.1, 0.2]
        with self.assertRaisesRegex(KeyError, "the scene's parameters: materials.red.base_color"):
            scene.params["materials.nope.base_color"] = [0.1, 0.2, 0.3]
        with self.assertRaisesRegex(ValueError, "not a finite number"):
            scene.params[RED] = [0.1, float("nan"), 0.3]
        with self.assertRaisesRegex(ValueError, "no_such_scene.toml"):
            vk.Scene(ROOT / "no_such_scene.toml")
        with self.assertRaisesRegex(ValueError, r"adjoint: shape \(4, 4, 3\)"):
            vk.gradient(scene, np.zeros((4, 4, 3)))
        with self.assertRaisesRegex(ValueError, "spp"):
            vk.optimise(scene, iterations=1, spp=0, quiet=True)
        with self.assertRaisesRegex(ValueError, "no_such_setting"):
            vk.optimise(scene, iterations=1, no_such_setting=3, quiet=True)
        for e in [ValueError("x"), vk.Error("y")]:
            self.assertNotIn("\n", str(e))


class GradientTests(unittest.TestCase):
    def test_gradient_agrees_with_finite_differences(self):
        scene = cornell()
        w, h = scene.film
        adjoint = np.full((h, w, 3), 1.0 / (w * h * 3), dtype=np.float32)
        estimates = np.array([vk.gradient(scene, adjoint, spp=64, seed=s)[RED] for s in range(4)])
        mean, se = estimates.mean(axis=0), estimates.std(axis=0, ddof=1) / 2
        for c in range(3):
            fd = fd_of_mean(scene, RED, c)
            self.assertLess(abs(mean[c] - fd), 4 * se[c] + 0.05 * abs(fd) + 1e-4, f"channel {c}: {mean[c]} vs finite differences {fd}")
        self.assertTrue(np.all(mean > 0), "a brighter wall brightens the image")


class JaxTests(unittest.TestCase):
    def setUp(self):
        try:
            import jax  # noqa: F401
        except ImportError:
            if "jax" in os.environ.get("VKINVERSE_REQUIRE_FRAMEWORKS", "").split():
                self.fail("jax is not installed, and VKINVERSE_REQUIRE_FRAMEWORKS (scripts/test.sh) requires it")
            self.skipTest("jax is not installed")

    def test_jax_grad_is_vkinverse_gradient_and_agrees_with_finite_differences(self):
        import jax
        import jax.numpy as jnp

        import vkinverse.jax as vkj

        scene = cornell()
        color = jnp.array(scene.params[RED])

        def mean_image(c):
            return jnp.mean(vkj.render(scene, {RED: c}, spp=16, seed=5, grad_spp=64))

        value = mean_image(color)
        self.assertAlmostEqual(float(value), float(np.mean(vk.render(scene, spp=16, seed=5))), places=6)
        check_wrapper_gradient(scene, np.array(jax.grad(mean_image)(color)))


class TorchTests(unittest.TestCase):
    def setUp(self):
        try:
            import torch  # noqa: F401
        except ImportError:
            if "torch" in os.environ.get("VKINVERSE_REQUIRE_FRAMEWORKS", "").split():
                self.fail("torch is not installed, and VKINVERSE_REQUIRE_FRAMEWORKS (scripts/test.sh) requires it")
            self.skipTest("torch is not installed")

    def test_torch_backward_is_vkinverse_gradient(self):
        import torch

        import vkinverse.torch as vkt

        scene = cornell()
        color = torch.tensor(np.array(scene.params[RED]), requires_grad=True)
        image = vkt.render(scene, {RED: color}, spp=16, seed=5, grad_spp=64)
        image.mean().backward()
        check_wrapper_gradient(scene, color.grad.numpy())


class OptimiseTests(unittest.TestCase):
    def setUp(self):
        self.dir = Path(tempfile.mkdtemp(prefix="vkinverse-py-"))

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def test_builtin_loss_run_recovers_the_wall_and_logs_every_iteration(self):
        scene = cornell()
        rows = []
        result = vk.optimise(scene, optimiser="adam", iterations=60, lr=0.05, target_spp=256, callback=rows.append, quiet=True)
        self.assertEqual(len(rows), 60)
        self.assertEqual(list(result.log["iteration"]), list(range(61)))
        error = np.abs(result.params[RED] - np.array([0.63, 0.065, 0.05])).max()
        self.assertLess(error, 0.08, f"recovered {result.params[RED]}")
        self.assertLess(result.log["param_error"][-1], result.log["param_error"][0] / 3)

    def test_python_l1_loss_recovers_the_wall(self):
        scene = cornell()
        target = np.array(vk.render(scene, spp=256, seed=99))
        truth = np.array(scene.params[RED])

        def l1(image):
            d = image - target
            return float(np.abs(d).mean()), (np.sign(d) / d.size).astype(np.float32)

        calls = []
        start = np.frombuffer(scene._native.param_start(RED)[0], np.float32)
        result = vk.optimise(scene, optimiser="adam", iterations=60, loss=l1, lr=0.05, callback=calls.append, quiet=True)
        self.assertEqual(len(calls), 60)
        error = np.abs(result.params[RED] - truth).max()
        self.assertLess(error, 0.08, f"recovered {result.params[RED]} of {truth}")
        self.assertLess(error, np.abs(start - truth).max() / 3, f"from {start}")
        # The loss is of a 4-spp render: its noise floor, not its trend, ends the run.
        self.assertTrue(np.all(np.isfinite(result.log["loss"])))
        with self.assertRaisesRegex(ValueError, "out_dir: a Python-loss run writes no run directory"):
            vk.optimise(scene, optimiser="adam", loss=l1, iterations=1, out_dir=self.dir / "run", quiet=True)

    def python_meta_run(self, spec, iterations=60):
        """A Python L1 loss run with the meta-estimator `spec`: (result, truth, start, the
        images the loss was called on)."""
        scene = cornell()
        target = np.array(vk.render(scene, spp=256, seed=99))
        truth = np.array(scene.params[RED])
        images = []

        def l1(image):
            images.append(np.array(image))
            d = image - target
            return float(np.abs(d).mean()), (np.sign(d) / d.size).astype(np.float32)

        start = np.frombuffer(scene._native.param_start(RED)[0], np.float32)
        rows = []
        result = vk.optimise(scene, optimiser=spec, iterations=iterations, loss=l1, lr=0.05, callback=rows.append, quiet=True)
        self.assertEqual(len(rows), iterations)
        self.assertEqual(list(result.log["iteration"]), list(range(1, iterations + 1)))
        self.assertTrue(np.all(np.isfinite(result.log["loss"])))
        # Three calls per iteration (the primal render, then θ_i and θ_{i-1} with one seed),
        # one at the first, which has no θ_{i-1}.
        self.assertEqual(len(images), 1 + 3 * (iterations - 1))
        return result, truth, start, images

    def test_python_l1_loss_with_meta_recovers_the_wall(self):
        result, truth, start, images = self.python_meta_run("meta")
        error = np.abs(result.params[RED] - truth).max()
        self.assertLess(error, 0.08, f"recovered {result.params[RED]} of {truth}")
        self.assertLess(error, np.abs(start - truth).max() / 3, f"from {start}")
        # The finite difference's two renders share their random numbers: they differ by
        # the step of the red wall alone, far less than two renders of one θ with seeds of
        # their own (the primal render and the first of them).
        crn = np.mean([np.abs(images[k + 1] - images[k + 2]).mean() for k in range(1, len(images), 3)])
        independent = np.mean([np.abs(images[k] - images[k + 1]).mean() for k in range(1, len(images), 3)])
        self.assertLess(crn, independent / 5, f"{crn} vs {independent}")

    def test_python_l1_loss_with_meta_seed_recovers_the_wall(self):
        result, truth, start, _ = self.python_meta_run("meta-seed")
        error = np.abs(result.params[RED] - truth).max()
        self.assertLess(error, 0.08, f"recovered {result.params[RED]} of {truth}")
        self.assertLess(error, np.abs(start - truth).max() / 3, f"from {start}")

    def test_python_loss_sums_over_every_sensor(self):
        # The Cornell box seen by a second camera: a Python loss is called as fn(image,
        # sensor) on each sensor's render, and the run recovers the wall from both.
        text = CORNELL.read_text().replace('file = "meshes/', f'file = "{CORNELL.parent}/meshes/')
        text += "\n[[sensors]]\norigin = [0.6, 1.2, 3.6]\ntarget = [0, 1, 0]\nfov_y = 40\n"
        path = self.dir / "two.toml"
        path.write_text(text)
        scene = vk.Scene(path, film=(24, 24))
        self.assertEqual(scene.sensors, 2)
        targets = [np.array(vk.render(scene, spp=128, seed=99, sensor=k)) for k in range(2)]
        truth = np.array(scene.params[RED])
        seen = []

        def l1(image, sensor):
            seen.append(sensor)
            d = image - targets[sensor]
            return float(np.abs(d).mean()), (np.sign(d) / d.size).astype(np.float32)

        start = np.frombuffer(scene._native.param_start(RED)[0], np.float32)
        result = vk.optimise(scene, optimiser="meta", iterations=30, loss=l1, lr=0.05, quiet=True)
        # Per iteration 3 renders (1 at the first), each of both sensors, in sensor order.
        self.assertEqual(seen, [0, 1] * (1 + 3 * 29))
        error = np.abs(result.params[RED] - truth).max()
        self.assertLess(error, np.abs(start - truth).max() / 2, f"recovered {result.params[RED]} of {truth} from {start}")
        with self.assertRaisesRegex(ValueError, r"2 sensors: a Python loss is then called as fn\(image, sensor\)"):
            vk.optimise(scene, optimiser="adam", iterations=1, loss=lambda image: (0.0, image * 0), quiet=True)

    def test_python_loss_with_meta_refuses_what_it_cannot_do(self):
        scene = cornell()

        def l2(image):
            return float((image**2).mean()), (2 * image / image.size).astype(np.float32)

        for spec, message in [
            ("meta@carry=0.1", "carried primal image needs a built-in loss"),
            ("meta@decay_f=2", "decay_f"),
            ("metta", "unknown optimiser"),
        ]:
            with self.assertRaisesRegex(ValueError, message):
                vk.optimise(scene, optimiser=spec, loss=l2, iterations=1, quiet=True)
        with self.assertRaisesRegex(ValueError, "target_spp"):
            vk.optimise(scene, optimiser="meta", loss=l2, iterations=1, target_spp=4, quiet=True)
        with self.assertRaisesRegex(ValueError, "out_dir"):
            vk.optimise(scene, optimiser="meta", loss=l2, iterations=1, out_dir=self.dir / "run", quiet=True)
        # carry=0 spelled out is what a Python loss runs anyway.
        result = vk.optimise(scene, optimiser="meta@carry=0", loss=l2, iterations=2, quiet=True)
        self.assertEqual(len(result.log["loss"]), 2)


    def test_callback_false_stops_and_the_run_resumes(self):
        scene = cornell()
        out = self.dir / "run"
        first = vk.optimise(scene, optimiser="adam", iterations=6, target_spp=16, checkpoint_every=2, out_dir=out, callback=lambda row: row["iteration"] < 3, quiet=True)
        self.assertTrue(first.interrupted)
        self.assertEqual(first.log["iteration"][-1], 3)
        self.assertTrue((out / "log.csv").exists())
        rest = vk.optimise(scene, optimiser="adam", iterations=6, target_spp=16, checkpoint_every=2, out_dir=out, resume=True, quiet=True)
        self.assertFalse(rest.interrupted)
        self.assertEqual(list(rest.log["iteration"]), list(range(7)))
        # The run's pictures, as the command line writes them.
        for name in ["preview.png", "target.exr", "start.exr", "final.exr"]:
            self.assertTrue((out / name).exists(), name)

    def test_ctrl_c_raises_keyboard_interrupt_and_leaves_a_resumable_run(self):
        scene = cornell()
        out = self.dir / "run"

        def interrupt(row):
            if row["iteration"] == 2:
                signal.raise_signal(signal.SIGINT)

        with self.assertRaises(KeyboardInterrupt):
            vk.optimise(scene, optimiser="adam", iterations=6, target_spp=16, out_dir=out, callback=interrupt, quiet=True)
        self.assertTrue((out / "log.csv").exists(), os.listdir(out))
        rest = vk.optimise(scene, optimiser="adam", iterations=6, target_spp=16, out_dir=out, resume=True, quiet=True)
        self.assertEqual(rest.log["iteration"][-1], 6)



class HostOptimiserTests(unittest.TestCase):
    def test_steps_equal_the_gpu_passes_of_the_command_lines_replay(self):
        """The same streams (gradients, finite differences, half-sample sums) through
        vk.HostOptimiser and through `vkinverse replay` (the renderer's optimiser passes):
        the same trajectory, to float32 rounding."""
        exe = binary()
        rng = np.random.default_rng(3)
        steps, n = 12, 5
        init = rng.uniform(0.2, 0.8, n).astype(np.float32)
        streams = {
            "grads": (rng.normal(0, 1, (steps, n)) + 0.5).astype(np.float32),
            "fd": rng.normal(0, 0.1, (steps, n)).astype(np.float32),
        }
        streams["gh"] = (streams["grads"] / 2 + rng.normal(0, 0.2, (steps, n))).astype(np.float32)
        streams["fh"] = (streams["fd"] / 2 + rng.normal(0, 0.02, (steps, n))).astype(np.float32)
        d = Path(tempfile.mkdtemp(prefix="vkinverse-py-"))
        try:
            np.save(d / "init.npy", init)
            for k, a in streams.items():
                np.save(d / f"{k}.npy", a)
            for spec in ["meta", "meta-seed", "meta@fdvar=scaled@step=snr", "adam"]:
                args = [exe, "replay", "--optimiser", spec, "--lr", "0.05", "--range", "0,1", "--init", d / "init.npy"]
                args += [d / "grads.npy", d / "fd.npy", "--halves", f"{d / 'gh.npy'},{d / 'fh.npy'}", "-o", d / "traj.npy"]
                subprocess.run([str(a) for a in args], check=True, capture_output=True)
                expected = np.load(d / "traj.npy")
                opt = vk.HostOptimiser(spec, [(n, 0.05, 0.0, 1.0)])
                theta, trajectory = init, [init]
                for i in range(steps):
                    theta = opt.step(theta, streams["grads"][i], streams["fd"][i], streams["gh"][i], streams["fh"][i])
                    trajectory.append(theta)
                np.testing.assert_allclose(np.array(trajectory), expected, rtol=0, atol=2e-6, err_msg=spec)
                self.assertGreater(np.abs(expected[-1] - init).max(), 0.1, f"{spec}: the streams move θ")
                diag = opt.diagnostics()
                self.assertEqual(len(diag), 1)
                self.assertEqual(diag[0]["elements"], n)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def test_meta_with_exact_gradients_finds_a_quadratics_minimum(self):
        """f(θ) = Σ c·(θ − θ*)²/2 in two groups with exact ⟨F⟩ = c·(θ − θ*) and exact
        ⟨ΔF⟩: meta settles at θ* (halves equal to half the total: no variance)."""
        c = np.array([1.0, 4.0, 0.5], np.float32)
        best = np.array([0.3, -0.2, 0.7], np.float32)
        opt = vk.HostOptimiser("meta", [(1, 0.1, -1.0, 1.0), (2, 0.1, -1.0, 1.0)])
        self.assertEqual((opt.kind, opt.needs_fd, opt.needs_halves, len(opt)), ("meta", True, True, 3))
        theta, prev = np.zeros(3, np.float32), np.zeros(3, np.float32)
        for _ in range(200):
            g, fd = c * (theta - best), c * (theta - prev)
            prev = theta
            theta = opt.step(theta, g, fd, g / 2, fd / 2)
        np.testing.assert_allclose(theta, best, atol=1e-3)
        self.assertEqual(len(opt.diagnostics()), 2)

    def test_bad_input_raises(self):
        with self.assertRaisesRegex(ValueError, "unknown optimiser"):
            vk.HostOptimiser("nope", [(1, 0.1, 0.0, 1.0)])
        with self.assertRaisesRegex(ValueError, "range"):
            vk.HostOptimiser("meta", [(1, 0.1, 1.0, 0.0)])
        opt = vk.HostOptimiser("meta", [(2, 0.1, 0.0, 1.0)])
        with self.assertRaisesRegex(ValueError, "half-sample"):
            opt.step(np.zeros(2), np.ones(2), np.zeros(2))
        with self.assertRaisesRegex(ValueError, "length 3, expected 2"):
            opt.step(np.zeros(2), np.ones(3), np.zeros(2), np.zeros(2), np.zeros(2))


if __name__ == "__main__":
    unittest.main()
