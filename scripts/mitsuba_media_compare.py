#!/usr/bin/env python3
"""Compares vkinverse's medium with Mitsuba 3's on a heterogeneous volume, absorbing or
(--albedo above 0) scattering:

  a. images: a box [-1, 1]^3 of absorbing medium (a smooth random density grid of N^3
     voxels, no emission, no scattering) in front of a constant environment, one
     perspective camera. vkinverse: `[[media]]` with the density as a .npy grid, emission
     0, the default step of 0.5 voxels, rendered with `vkinverse render`. Mitsuba: a
     `cube` shape with a `null` BSDF whose interior is a `heterogeneous` medium of albedo 0
     and sigma_t a `gridvolume` read from a .vol file (trilinear, its unit cube mapped onto
     the same box), rendered with `volpath`. Image means per channel and per-pixel
     differences (8 x 8 pixel blocks) against both renderers' Monte Carlo noise, from two
     independent renders each (statistics of scripts/mitsuba_compare.py);
  b. the gradient of the l2 loss with respect to the density grid, at a start grid (the
     reference times --init-factor) against the reference's image: both renderers
     differentiate the same linear functional sum(A * image), with A = dLoss/dImage taken
     from vkinverse's nearly noise-free renders of the start and the reference, so that
     only the image's derivative is compared. vkinverse: `vk.gradient` of the Python
     package (pip install ./python); Mitsuba: `prbvolpath` with dr.enable_grad on the
     volume's data. Mean and standard error over independent rounds of each; the sum over
     the voxels (z of the difference), the correlation of the per-voxel means (against
     the correlation their noise allows: the split-half reliability of each side), and
     the relative l2 difference against the one expected from noise alone;
  c. time per Adam iteration on the density grid (render, loss, gradient, step), at each
     --res: `vkinverse optimise --optimiser adam` against Mitsuba prbvolpath +
     mi.ad.Adam at the same samples per pixel. Mitsuba's kernels run asynchronously: each
     timed iteration evaluates its step and reads the loss back, then waits for every
     kernel (dr.sync_thread()) before the clock stops.

    python3 scripts/mitsuba_media_compare.py --grid 32 --res 128,256 --out /tmp/media-cmp
    python3 scripts/mitsuba_media_compare.py --albedo 0.8 --g 0.3 --out /tmp/media-scatter
    python3 scripts/mitsuba_media_compare.py --albedo 0.9 --albedo-grid --g 0.3 --parts a --out /tmp/media-albedo
    python3 scripts/mitsuba_media_compare.py --shape sphere --albedo 0.8 --g 0.3 --out /tmp/media-sphere

With --shape sphere the medium fills the sphere inscribed in the box instead of the box:
Mitsuba's `sphere` shape (exact) with the null BSDF, and vkinverse's `[[media]]` box with
`mesh` a UV sphere of --sphere-segments around (as Mitsuba's importer tessellates it).
The grid spans the box on both.

With --albedo above 0 the medium scatters (a Henyey-Greenstein phase function of --g on
both; isotropic at 0); with --albedo-grid its albedo is a smooth random RGB grid of
--grid^3 voxels between 0.3 and --albedo (vkinverse: albedo.npy; Mitsuba: a three-channel
gridvolume placed as the density's) and both trace paths of up to --max-depth segments (Mitsuba:
scattering events) through it: vkinverse samples collisions by inverting its marched
transmittance, Mitsuba by delta tracking.

Conventions. Both look the grid up trilinearly between voxel centres, clamped at the
faces, over the whole box (Mitsuba's gridvolume: filter_type "trilinear", wrap "clamp",
to_world mapping [0, 1]^3 onto the box; vkinverse: glsl/lib/media.glsl), x fastest in
memory ([z, y, x] arrays on both sides). sigma_t = scale * density on both.

How each estimates the transmittance: vkinverse marches each ray through the box in
stratified steps of 0.5 voxels (one jitter per ray) and multiplies exp(-sigma dt): nearly
noise-free, with a quadrature error far below Mitsuba's noise. Mitsuba's volpath samples
free-flight distances by delta tracking against a majorant (the grid's maximum times
scale, which the heterogeneous medium computes itself); with albedo 0 a real collision
ends the path, so each sample's transmittance is 0 or 1 (a binary estimate), and
prbvolpath differentiates the same tracking. Equal samples per pixel are therefore not
equal noise: at the default settings Mitsuba needs many more samples for the same image
noise, and its gradient is far noisier. No majorant or other setting was needed: albedo
0 with the default majorant ran as it is.

Mitsuba is a peer to measure against, not a dependency: it is imported only in the
scripts. Needs `pip install mitsuba numpy`, Debian's libllvm19 and, for part b, the
vkinverse Python package.
"""

import argparse
import json
import shutil
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba_compare as mc  # noqa: E402  (shared functions: Mitsuba set-up, vkinverse runs, statistics)

BOX_MIN, BOX_MAX = [-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]
ENVIRONMENT = [0.4, 0.5, 0.6]
SENSOR = {"origin": [1.2, 0.9, 3.4], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 40.0}
NAME = "cloud"
PARAM = f"media.{NAME}.density"
# Mitsuba's parameter that holds the grid (the container's interior medium's sigma_t).
MITSUBA_KEY = "container.interior_medium.sigma_t.data"


def sphere_obj(segments):
    """A UV sphere of radius 1 at the origin as OBJ text: `segments` around, half as many
    from pole to pole, fans at the poles, wound out."""
    import math
    nu, nv = segments, segments // 2
    lines = []
    for j in range(nv + 1):
        th = math.pi * j / nv
        for i in range(nu + 1):
            ph = 2 * math.pi * i / nu
            lines.append(f"v {math.sin(th) * math.cos(ph):.9g} {math.sin(th) * math.sin(ph):.9g} {math.cos(th):.9g}")

    def at(i, j):
        return j * (nu + 1) + i + 1

    for j in range(nv):
        for i in range(nu):
            a, b, c, d = at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)
            if j > 0:
                lines.append(f"f {a} {d} {b}")
            if j + 1 < nv:
                lines.append(f"f {b} {d} {c}")
    return "\n".join(lines) + "\n"


def density_grid(np, n, seed):
    """A smooth random density of n^3 voxels ([z, y, x], x fastest): a sum of 8 Gaussian
    blobs (centres in the middle 60 % of the box, radii 0.1 to 0.25 of its side, peaks 1
    to 3 each), the recipe of `vkinverse bench --media`'s grids with other random numbers."""
    rng = np.random.default_rng(seed)
    c = (np.arange(n) + 0.5) / n
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    d = np.zeros((n, n, n))
    for _ in range(8):
        centre = 0.2 + 0.6 * rng.random(3)
        radius = 0.1 + 0.15 * rng.random()
        amp = 1.0 + 2.0 * rng.random()
        r2 = (x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2
        d += amp * np.exp(-r2 / (2 * radius * radius))
    return d.astype(np.float32)


def albedo_grid(np, n, top, seed):
    """A smooth random RGB albedo of n^3 voxels ([z, y, x, 3]) between 0.3 and `top`: each
    channel a density_grid of its own seed, normalised to [0, 1] and mapped there."""
    channels = []
    for c in range(3):
        d = density_grid(np, n, seed + 100 + c).astype(np.float64)
        channels.append(0.3 + (top - 0.3) * (d - d.min()) / max(d.max() - d.min(), 1e-12))
    return np.stack(channels, axis=-1).astype(np.float32)


def write_vk_scene(np, folder, n, res, density, args, spp, init):
    """vkinverse's scene: the medium's box with `density` as its .npy grid, emission 0, and
    the density grid as an optimised parameter starting at `init` (a number)."""
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "density.npy", density.astype(np.float32))
    albedo = args.albedo
    if args.albedo_grid:
        np.save(folder / "albedo.npy", albedo_grid(np, n, args.albedo, args.seed))
        albedo = '"albedo.npy"'
    s = SENSOR
    mesh = ""
    if args.shape == "sphere":
        (folder / "sphere.obj").write_text(sphere_obj(args.sphere_segments))
        mesh = 'mesh = "sphere.obj"'
    toml = f"""# The absorbing medium of scripts/mitsuba_media_compare.py.
[film]
width = {res}
height = {res}

[integrator]
max_depth = {args.max_depth if args.albedo > 0 else 2}

[[sensors]]
origin = {s['origin']}
target = {s['target']}
up = {s['up']}
fov_y = {s['fov_y']}

[environment]
constant = {ENVIRONMENT}

[[media]]
name = "{NAME}"
min = {BOX_MIN}
max = {BOX_MAX}
{mesh}
density = "density.npy"
emission = 0.0
scale = {args.scale}
step = 0.5
albedo = {albedo}
g = {args.g}

[optimise]
spp = {spp}
primal_spp = {spp}

[[optimise.params]]
target = "{PARAM}"
init = {init}
range = [0.0, 100.0]
grid = [{n}, {n}, {n}]
"""
    (folder / "scene.toml").write_text(toml)
    return folder / "scene.toml"


def mitsuba_scene(mi, vol_path, res, args, integrator, spp):
    s = SENSOR
    size = [b - a for a, b in zip(BOX_MIN, BOX_MAX)]
    to_world = mi.ScalarTransform4f().translate(BOX_MIN).scale(size)
    return mi.load_dict({
        "type": "scene",
        # A path ends at its first real collision (albedo 0); null crossings of the cube's
        # faces and null collisions in the medium do not count against max_depth.
        "integrator": {"type": integrator, "max_depth": args.max_depth if args.albedo > 0 else 64, "rr_depth": 1000},
        "sensor": {
            "type": "perspective",
            "fov_axis": "y",
            "fov": s["fov_y"],
            "to_world": mi.ScalarTransform4f().look_at(origin=s["origin"], target=s["target"], up=s["up"]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgb", "rfilter": {"type": "box"}},
        },
        # Mitsuba's cube spans [-1, 1]^3, the box; its sphere is the one inscribed in it.
        "container": {
            "type": args.shape,
            "bsdf": {"type": "null"},
            "interior": {
                "type": "heterogeneous",
                "albedo": ({"type": "gridvolume", "filename": str(vol_path.parent / "albedo.vol"), "filter_type": "trilinear",
                            "wrap_mode": "clamp", "to_world": to_world} if args.albedo_grid else args.albedo),
                "phase": {"type": "hg", "g": args.g} if args.g != 0 else {"type": "isotropic"},
                "scale": args.scale,
                "sigma_t": {"type": "gridvolume", "filename": str(vol_path), "filter_type": "trilinear",
                            "wrap_mode": "clamp", "to_world": to_world},
            },
        },
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": ENVIRONMENT}},
    })


def read_exr(np, mi, path):
    return np.array(mi.Bitmap(str(path)))[..., :3].astype(np.float64)


def part_a(np, mi, vk, scene_path, vol, res, args, out):
    mscene = mitsuba_scene(mi, vol, res, args, "volpath", args.spp)

    def mitsuba_render(seed):
        t = time.perf_counter()
        img = np.array(mi.render(mscene, spp=args.spp, seed=seed)).astype(np.float64)  # read back: synchronous
        return time.perf_counter() - t, img

    mitsuba_render(0)  # compiles the kernels
    m = [mitsuba_render(s) for s in (1, 2)]
    v = []
    for s in (1, 2):
        path = out / f"vkinverse_seed{s}.exr"
        dt, _, _ = mc.run_vk(vk, ["render", scene_path, "--spp", args.vk_spp, "--seed", s, "--quiet", "-o", path])
        v.append((dt, read_exr(np, mi, path)))
    for s, (_, img) in zip((1, 2), m):
        mi.util.write_bitmap(str(out / f"mitsuba_seed{s}.exr"), img.astype(np.float32), write_async=False)
    cmp = mc.image_comparison(np, m[0][1], m[1][1], v[0][1], v[1][1])
    cmp.pop("_z", None)
    # Per-pixel z of the difference of the two renderers' means, against each one's
    # per-pixel variance from its two renders (pixels of both channels and both renders).
    ma, va = 0.5 * (m[0][1] + m[1][1]), 0.5 * (v[0][1] + v[1][1])
    var = 0.25 * (m[0][1] - m[1][1]) ** 2 + 0.25 * (v[0][1] - v[1][1]) ** 2
    # Two renders give a variance estimate of one degree of freedom; pooled over each 8 x 8
    # block (a smooth image: neighbours share their noise level) it is steadier.
    b = mc.BLOCK
    h, w = (res // b) * b, (res // b) * b
    pooled = var[:h, :w].reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))
    pooled = np.repeat(np.repeat(pooled, b, axis=0), b, axis=1)
    seen = pooled > 0
    z = (ma[:h, :w] - va[:h, :w])[seen] / np.sqrt(pooled[seen])
    cmp["pixels"] = {"count": int(z.size), "mean_z": float(z.mean()), "rms_z": float(np.sqrt((z ** 2).mean())),
                     "abs_z_over_4": int((np.abs(z) > 4).sum()),
                     "unseen": int((~seen).sum())}
    cmp["mitsuba_s"] = [t for t, _ in m]
    cmp["vkinverse_s"] = [t for t, _ in v]
    return cmp


def print_a(res, cmp, args):
    print(f"\n(a) images {res}x{res}: Mitsuba volpath {args.spp} spp, vkinverse {args.vk_spp} spp, two renders each")
    for c, ch in zip("rgb", cmp["channel_means"]):
        print(f"  {c}: mitsuba {ch['mitsuba']:.5f}  vkinverse {ch['vkinverse']:.5f}  "
              f"diff {ch['diff'] / ch['vkinverse'] * 100:+.3f} %  z {ch['z']:+.2f}")
    bl = cmp["blocks"]
    print(f"  {bl['size']}x{bl['size']} blocks: {bl['abs_z_over_4']} of {bl['count']} beyond 4 se, max |z| {bl['max_abs_z']:.2f} "
          f"(worst at row {bl['worst']['row']}, col {bl['worst']['col']}, {bl['worst']['channel']}: "
          f"{bl['worst']['relative_diff'] * 100:+.2f} %)")
    px = cmp["pixels"]
    print(f"  pixels: z of the difference against both renderers' noise (variance pooled over 8x8 blocks): "
          f"mean {px['mean_z']:+.3f}, rms {px['rms_z']:.3f} (1 if they agree), {px['abs_z_over_4']} of {px['count']} beyond 4")
    print(f"  mean relative error {cmp['mre_mitsuba_vs_vkinverse']:.4f} vs {cmp['mre_expected_if_equal']:.4f} expected from "
          f"noise alone (Mitsuba's own {cmp['mre_mitsuba_noise']:.4f}, vkinverse's {cmp['mre_vkinverse_noise']:.5f})")
    print(f"  render time: Mitsuba {min(cmp['mitsuba_s']):.2f} s, vkinverse {min(cmp['vkinverse_s']):.2f} s (process)")


def part_b(np, dr, mi, vol, scene_path, reference, args, out):
    try:
        import vkinverse as vkpy
    except ImportError as e:
        mc.fail(f"part b needs the vkinverse Python package ({e}): pip install ./python")
    res = args.grad_res
    start = (args.init_factor * reference).astype(np.float32)[..., None]
    scene = vkpy.Scene(str(scene_path), film=(res, res))
    # The reference's image and the start's, at many samples (vkinverse's march is nearly
    # noise-free), give the adjoint of the l2 loss mean((I - T)^2) over pixels and channels.
    scene.params[PARAM] = reference[..., None]
    target = vkpy.render(scene, spp=args.vk_spp, seed=101).astype(np.float64)
    scene.params[PARAM] = start
    image = vkpy.render(scene, spp=args.vk_spp, seed=102).astype(np.float64)
    adjoint = (2.0 * (image - target) / image.size).astype(np.float32)
    loss = float(((image - target) ** 2).mean())

    vk_grads, vk_times = [], []
    vkpy.gradient(scene, adjoint, spp=args.grad_spp, seed=0)  # warm-up (pipelines)
    for r in range(args.rounds):
        t = time.perf_counter()
        g = vkpy.gradient(scene, adjoint, spp=args.grad_spp, seed=1000 + r)[PARAM]
        vk_times.append(time.perf_counter() - t)
        vk_grads.append(np.asarray(g, dtype=np.float64).reshape(-1))

    mscene = mitsuba_scene(mi, vol, res, args, "prbvolpath", args.grad_spp)
    params = mi.traverse(mscene)
    params[MITSUBA_KEY] = mi.TensorXf(start)
    dr.enable_grad(params[MITSUBA_KEY])
    params.update()
    adjoint_t = mi.TensorXf(adjoint)
    m_grads, m_times = [], []
    for r in range(args.mitsuba_rounds + 1):
        t = time.perf_counter()
        img = mi.render(mscene, params, spp=args.grad_spp, seed=2000 + r)
        dr.backward(dr.sum(adjoint_t * img, axis=None))
        g = np.array(dr.grad(params[MITSUBA_KEY]), dtype=np.float64).reshape(-1)
        dr.sync_thread()
        dt = time.perf_counter() - t
        dr.clear_grad(params[MITSUBA_KEY])
        if r > 0:  # the first compiles the kernels
            m_grads.append(g)
            m_times.append(dt)

    V, M = np.array(vk_grads), np.array(m_grads)
    vm, mm = V.mean(0), M.mean(0)
    vse2, mse2 = V.var(0, ddof=1) / len(V), M.var(0, ddof=1) / len(M)
    vsum, msum = V.sum(1), M.sum(1)
    (vs, vs_se), (ms, ms_se) = mc.mean_se(list(vsum)), mc.mean_se(list(msum))

    def corr(a, b):
        a, b = a - a.mean(), b - b.mean()
        return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))

    def split_half(X):
        """The correlation of the means of the two halves of the rounds, stepped up to the
        whole (Spearman-Brown): how well the noisy mean correlates with its own
        expectation, squared."""
        h = len(X) // 2
        r = corr(X[:h].mean(0), X[h:2 * h].mean(0))
        return 2 * r / (1 + r) if r > -1 else float("nan")

    rel_l2 = float(np.linalg.norm(mm - vm) / np.linalg.norm(vm))
    rel_l2_noise = float(np.sqrt((vse2 + mse2).sum()) / np.linalg.norm(vm))
    rel_m, rel_v = split_half(M), split_half(V)
    out_b = {
        "res": res, "grid": int(reference.shape[0]), "spp": args.grad_spp, "init_factor": args.init_factor, "loss": loss,
        "rounds": args.rounds, "mitsuba_rounds": args.mitsuba_rounds,
        "sum": {"vkinverse": float(vs), "vkinverse_se": float(vs_se), "mitsuba": float(ms), "mitsuba_se": float(ms_se),
                "z": float((ms - vs) / np.hypot(vs_se, ms_se))},
        "correlation": corr(mm, vm),
        # The correlation two estimates of equal expectation reach through their noise
        # alone: sqrt(reliability_m * reliability_v).
        "correlation_ceiling": float(np.sqrt(max(rel_m, 0) * max(rel_v, 0))),
        "reliability": {"mitsuba": rel_m, "vkinverse": rel_v},
        "relative_l2": rel_l2, "relative_l2_expected_from_noise": rel_l2_noise,
        "vkinverse_per_estimate_s": statistics.median(vk_times),
        "mitsuba_per_estimate_s": statistics.median(m_times),
    }
    np.save(out / "grad_vkinverse.npy", vm.reshape(reference.shape).astype(np.float32))
    np.save(out / "grad_mitsuba.npy", mm.reshape(reference.shape).astype(np.float32))
    return out_b


def print_b(b):
    print(f"\n(b) d(l2 loss)/d density grid ({b['grid']}^3 voxels) at {b['init_factor']} x the reference, {b['res']}x{b['res']}, "
          f"{b['spp']} spp per estimate; mean ± se of {b['mitsuba_rounds']} (Mitsuba prbvolpath) and {b['rounds']} (vkinverse) estimates")
    s = b["sum"]
    print(f"  sum over voxels: Mitsuba {s['mitsuba']:+.5e} ± {s['mitsuba_se']:.2e}, vkinverse {s['vkinverse']:+.5e} ± "
          f"{s['vkinverse_se']:.2e}: ratio {s['mitsuba'] / s['vkinverse']:.4f}, z {s['z']:+.2f}")
    print(f"  per-voxel correlation of the means {b['correlation']:.4f} (noise allows at most {b['correlation_ceiling']:.4f}: "
          f"split-half reliability Mitsuba {b['reliability']['mitsuba']:.4f}, vkinverse {b['reliability']['vkinverse']:.4f})")
    print(f"  relative l2 difference of the means {b['relative_l2']:.4f} vs {b['relative_l2_expected_from_noise']:.4f} "
          f"expected from both sides' noise alone")
    print(f"  time per gradient estimate: Mitsuba {b['mitsuba_per_estimate_s']:.3f} s (render + backward), vkinverse "
          f"{b['vkinverse_per_estimate_s']:.3f} s (vk.gradient: the adjoint pass)")


def part_c(np, dr, mi, vk, scene_path, vol, reference, res, args, out):
    spp, iters, lr = args.opt_spp, args.iterations, args.lr
    # The target: vkinverse renders the scene's own values (the reference) at target_spp;
    # Mitsuba gets vkinverse's image of the reference at the same samples.
    target_path = out / "target.exr"
    mc.run_vk(vk, ["render", scene_path, "--spp", args.vk_spp, "--seed", 7, "--quiet", "-o", target_path])
    target = mi.TensorXf(read_exr(np, mi, target_path).astype(np.float32))
    mscene = mitsuba_scene(mi, vol, res, args, "prbvolpath", spp)
    params = mi.traverse(mscene)
    n = reference.shape[0]
    params[MITSUBA_KEY] = mi.TensorXf(np.full((n, n, n, 1), args.opt_init, np.float32))
    params.update()
    opt = mi.ad.Adam(lr=lr)
    opt[MITSUBA_KEY] = params[MITSUBA_KEY]
    params.update(opt)
    times = []

    def mitsuba_iterations(first, count):
        for it in range(first, first + count):
            t = time.perf_counter()
            img = mi.render(mscene, params, spp=spp, seed=it)
            loss = dr.mean(dr.square(img - target), axis=None)
            dr.backward(loss)
            opt.step()
            opt[MITSUBA_KEY] = dr.clip(opt[MITSUBA_KEY], 0.0, 100.0)
            params.update(opt)
            dr.eval(params[MITSUBA_KEY], opt[MITSUBA_KEY])
            float(np.array(loss).ravel()[0])
            dr.sync_thread()
            times.append(time.perf_counter() - t)

    opt_dir = out / "vk_adam"
    shutil.rmtree(opt_dir, ignore_errors=True)
    vk_args = ["optimise", scene_path, "--optimiser", "adam", "--iterations", iters, "--spp", spp, "--primal-spp", spp,
               "--target-spp", args.vk_spp, "--lr", lr, "--quiet", "-o", opt_dir]
    # Half of Mitsuba's iterations before vkinverse's run and half after, so that a change
    # in the machine's load shows in both medians.
    mitsuba_iterations(0, iters // 2)
    wall, _, _ = mc.run_vk(vk, vk_args)
    mitsuba_iterations(iters // 2, iters - iters // 2)
    # The first iterations compile Dr.Jit's kernels; the median leaves them out.
    steady = times[min(3, iters // 2 - 1):] if iters >= 8 else times
    return {
        "res": res, "iterations": iters, "spp": spp, "lr": lr,
        "mitsuba_per_iter_s": statistics.median(steady),
        "mitsuba_first_iter_s": times[0],
        "vkinverse_per_iter_s": mc.per_iteration_time(opt_dir / "log.csv"),
        "vkinverse_process_s": wall,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=int, default=32, help="voxels along each side of the density grid")
    ap.add_argument("--scale", type=float, default=0.5, help="sigma_t = scale * density")
    ap.add_argument("--seed", type=int, default=1, help="seed of the random density")
    ap.add_argument("--albedo", type=float, default=0.0, help="the medium's single-scattering albedo (0: absorbing only)")
    ap.add_argument("--albedo-grid", action="store_true", help="an RGB albedo grid between 0.3 and --albedo instead "
                    "of the constant --albedo")
    ap.add_argument("--g", type=float, default=0.0, help="Henyey-Greenstein mean cosine of a scattering medium")
    ap.add_argument("--max-depth", type=int, default=16, help="with --albedo above 0: vkinverse's max_depth (path "
                    "segments); Mitsuba counts its depth the same way")
    ap.add_argument("--res", default="128,256", help="comma-separated film sizes (square) of parts a and c")
    ap.add_argument("--spp", type=int, default=1024, help="part a: Mitsuba's samples per pixel")
    ap.add_argument("--vk-spp", type=int, default=64, help="vkinverse's samples per pixel of its renders (part a, the "
                    "adjoint and targets)")
    ap.add_argument("--grad-res", type=int, default=128, help="part b: film size")
    ap.add_argument("--grad-spp", type=int, default=16, help="part b: samples per pixel of each gradient estimate")
    ap.add_argument("--init-factor", type=float, default=0.5, help="part b: the start grid is the reference times this")
    ap.add_argument("--rounds", type=int, default=8, help="part b: vkinverse's independent gradient estimates")
    ap.add_argument("--mitsuba-rounds", type=int, default=64, help="part b: Mitsuba's independent gradient estimates")
    ap.add_argument("--iterations", type=int, default=10, help="part c: Adam iterations of each")
    ap.add_argument("--opt-spp", type=int, default=4, help="part c: samples per pixel of each iteration's render and "
                    "of its gradient")
    ap.add_argument("--opt-init", type=float, default=1.0, help="part c: the density's start value")
    ap.add_argument("--lr", type=float, default=0.05, help="part c: Adam's learning rate")
    ap.add_argument("--shape", choices=["cube", "sphere"], default="cube", help="the medium's container: the box, or the "
                    "sphere inscribed in it")
    ap.add_argument("--sphere-segments", type=int, default=96, help="with --shape sphere: vkinverse's tessellation")
    ap.add_argument("--parts", default="abc", help="which comparisons to run (subset of abc)")
    ap.add_argument("--vkinverse", help="vkinverse binary (default: $CARGO_TARGET_DIR or target/ release build)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.res = [int(r) for r in args.res.split(",")]
    np, dr, mi = mc.import_mitsuba()
    vk = mc.find_vkinverse(args.vkinverse)
    args.out.mkdir(parents=True, exist_ok=True)
    reference = density_grid(np, args.grid, args.seed)
    vol = args.out / "density.vol"
    mi.VolumeGrid(reference[..., None]).write(str(vol))
    if args.albedo_grid:
        mi.VolumeGrid(albedo_grid(np, args.grid, args.albedo, args.seed)).write(str(args.out / "albedo.vol"))
    results = {"grid": args.grid, "scale": args.scale, "density_max": float(reference.max()),
               "density_mean": float(reference.mean()), "mitsuba": mi.__version__, "a": {}, "c": {}}
    print(f"density grid {args.grid}^3, max {reference.max():.3f}, mean {reference.mean():.3f}, scale {args.scale}; "
          f"Mitsuba {mi.__version__} ({mc.VARIANT})")
    scenes = {}
    for res in sorted(set(args.res + ([args.grad_res] if "b" in args.parts else []))):
        folder = args.out / f"res-{res}"
        scenes[res] = (folder, write_vk_scene(np, folder, args.grid, res, reference, args, args.opt_spp, args.opt_init))
    if "a" in args.parts:
        for res in args.res:
            folder, path = scenes[res]
            results["a"][res] = part_a(np, mi, vk, path, vol, res, args, folder)
            print_a(res, results["a"][res], args)
    if "b" in args.parts:
        folder, path = scenes[args.grad_res]
        results["b"] = part_b(np, dr, mi, vol, path, reference, args, folder)
        print_b(results["b"])
    if "c" in args.parts:
        print(f"\n(c) Adam on the {args.grid}^3 density grid, {args.iterations} iterations, {args.opt_spp} spp "
              f"(primal and adjoint), lr {args.lr}")
        for res in args.res:
            folder, path = scenes[res]
            c = part_c(np, dr, mi, vk, path, vol, reference, res, args, folder)
            results["c"][res] = c
            print(f"  {res}x{res}: Mitsuba {c['mitsuba_per_iter_s'] * 1e3:.1f} ms per iteration (first "
                  f"{c['mitsuba_first_iter_s']:.2f} s), vkinverse {c['vkinverse_per_iter_s'] * 1e3:.1f} ms; "
                  f"ratio vk/mi {c['vkinverse_per_iter_s'] / c['mitsuba_per_iter_s']:.2f}")
    (args.out / "results.json").write_text(json.dumps(results, indent=1, default=str))
    print(f"\nresults in {args.out / 'results.json'}")


if __name__ == "__main__":
    main()
