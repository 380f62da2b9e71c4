#!/usr/bin/env python3
"""Compares vkinverse with Mitsuba 3 (variant llvm_ad_rgb, or --variant) on one scene file:

  a. images: `vkinverse render` against Mitsuba's `path` integrator at the same
     resolution, samples and depth; wall-time ratio and mean relative error, set against
     the Monte Carlo noise of each renderer (two independent renders of each);
  b. the gradient of the l2 loss with respect to every optimised constant colour of the
     scene at its `init` value: `vkinverse gradcheck --json` (its adjoint and its finite
     differences) against Mitsuba's `prb` integrator, each as a mean ± standard error over
     independent rounds, both against the same target image (Mitsuba's high-spp render,
     given to vkinverse as the target image of a copy of the scene); z-scores of each
     difference over the combined standard error;
  c. time per Adam iteration: `vkinverse optimise --optimiser adam` against Mitsuba
     prb + mi.ad.Adam with the scene's learning rate and sample counts.

`--res 64,256` runs everything once per film resolution (a copy of the scene's folder
with its [film] size replaced, in OUT/res-N/) and ends with a table of the time ratios
(vkinverse / Mitsuba) per resolution: render, gradient estimate, Adam iteration. Every
Mitsuba timing ends with its kernels finished: Dr.Jit launches them asynchronously, so
each timed span evaluates what it computed and waits (`dr.sync_thread()`) or reads a
value back before the clock stops.

Mitsuba is a peer to measure against, not a dependency of vkinverse: this script is the
only place it is imported, and it stops with a message when it is missing.

    python3 scripts/mitsuba_compare.py scenes/cornell/scene.toml --spp 1024 --out /tmp/cmp
    python3 scripts/mitsuba_compare.py scenes/cornell/scene.toml --res 64,256 --spp 256 \
        --parts ac --out /tmp/cmp

On a machine with an NVIDIA GPU, `--variant cuda_ad_rgb` compares against Mitsuba's CUDA
backend (OptiX) instead, with vkinverse on the same GPU through Vulkan.

Only what has an exact Mitsuba counterpart is translated: diffuse (Lambert) materials
with constant colours, OBJ meshes, one-sided area lights, a constant environment, pinhole
sensors. Anything else is refused rather than approximated, since an approximate peer
would turn every difference into noise. The one exception is asked for by name:
`--approximate-materials` translates principled materials with constant inputs to
Mitsuba's `principled` BSDF (base colour, metallic and roughness; its other inputs at
their defaults, `specular` 0.5 being the same 4 % reflectance at normal incidence), so
that a scene like the spiral can be timed against Mitsuba. The two models differ
(Mitsuba's diffuse lobe is Disney's, with retro-reflection; vkinverse's is Lambert's
weighted by both directions' Fresnel transmission), so the images are not expected to
agree and part b is refused; the run says so in its tables.

    python3 scripts/mitsuba_compare.py scenes/spiral/scene.toml --approximate-materials \
        --res 64,256 --spp 256 --parts ac --out /tmp/cmp-spiral
"""

import argparse
import csv
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
import tomllib
from pathlib import Path

# Mitsuba's variant: llvm_ad_rgb (the CPU backend) unless --variant names another.
VARIANT = "llvm_ad_rgb"
# Debian's LLVM 19, which Dr.Jit's LLVM backend loads at run time; an explicit
# DRJIT_LIBLLVM_PATH in the environment wins.
DEBIAN_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
# vkinverse's defaults where the scene file leaves a table out (src/scene/file.rs).
DEFAULT_MAX_DEPTH = 6
DEFAULT_RR_DEPTH = 5
# Relative errors are taken against max(mean of the two pixels, REL_FLOOR), so that
# nearly black pixels (shadowed corners) do not dominate the mean.
REL_FLOOR = 1e-2
# Side of the pixel blocks in which systematic differences are located.
BLOCK = 8
# A block whose standard error is below this share of its mean is "quiet": nearly free of
# noise (an emitter or the sky seen directly), so that float rounding and interpolation
# differences far below anything visible stand out in z; such blocks are counted apart.
QUIET = 2e-3
# --approximate-materials: principled materials translated to Mitsuba's principled BSDF.
APPROXIMATE = False
# The optimisable material inputs part c translates, by material type: vkinverse's field
# and the Mitsuba parameter (under the material's twosided wrapper) that holds it.
MITSUBA_FIELDS = {
    "diffuse": {"base_color": "brdf_0.reflectance.value"},
    "principled": {"base_color": "brdf_0.base_color.value", "metallic": "brdf_0.metallic.value",
                   "roughness": "brdf_0.roughness.value"},
}


def set_variant(name):
    global VARIANT
    VARIANT = name


def fail(msg, code=2):
    print(f"mitsuba_compare: {msg}", file=sys.stderr)
    sys.exit(code)


def import_mitsuba():
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(DEBIAN_LIBLLVM):
        os.environ["DRJIT_LIBLLVM_PATH"] = DEBIAN_LIBLLVM
    try:
        import numpy as np
        import drjit as dr
        import mitsuba as mi
    except ImportError as e:
        fail(
            f"Mitsuba 3 is not installed ({e}).\n"
            "  It is needed only by this comparison script, not by vkinverse: "
            "pip install mitsuba numpy"
        )
    try:
        mi.set_variant(VARIANT)
    except Exception as e:  # noqa: BLE001 - any failure here means the variant is unusable
        need = ("libLLVM: apt-get install libllvm19 and set "
                f"DRJIT_LIBLLVM_PATH={DEBIAN_LIBLLVM}") if VARIANT.startswith("llvm") else \
            "an NVIDIA GPU with its driver (libcuda, libnvoptix)"
        fail(f"Mitsuba's {VARIANT} variant is unavailable ({e}).\n  It needs {need}")
    return np, dr, mi


# ---------------------------------------------------------------------------------------
# Scene translation
# ---------------------------------------------------------------------------------------


def load_toml(path):
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        fail(f"{path}: {e}")


def obj_has_normals(path):
    with open(path) as f:
        return any(line.split()[:1] == ["vn"] for line in f)


def mitsuba_key(name):
    return "mat_" + "".join(c if c.isalnum() else "_" for c in name)


def opt_params(scene):
    """[(material, field, init, range, lr or None, Mitsuba parameter)] of every optimised
    constant material input that has a Mitsuba parameter (MITSUBA_FIELDS), in the scene's
    order."""
    types = {m["name"]: m.get("type", "diffuse") for m in scene.get("materials", [])}
    out = []
    for p in scene.get("optimise", {}).get("params", []):
        parts = p["target"].split(".")
        if len(parts) != 3 or parts[0] != "materials" or "texture" in p:
            continue
        if parts[2] not in MITSUBA_FIELDS.get(types.get(parts[1]), {}):
            continue
        init = p["init"]
        if parts[2] == "base_color":
            init = [float(v) for v in init] if isinstance(init, list) else [float(init)] * 3
        else:
            init = float(init[0] if isinstance(init, list) else init)
        key = f"{mitsuba_key(parts[1])}.{MITSUBA_FIELDS[types[parts[1]]][parts[2]]}"
        out.append((parts[1], parts[2], init, p.get("range", [0.0, 1.0]), p.get("lr"), key))
    return out


def color_params(scene):
    """[(material name, init)] of every optimised constant materials.NAME.base_color."""
    out = [(name, init) for name, field, init, _, _, _ in opt_params(scene) if field == "base_color"]
    if not out:
        fail("the scene optimises no constant materials.NAME.base_color; part b needs one")
    return out


def scene_dict(scene, scene_dir, integrator, spp, sensor=0, overrides=None):
    """Mitsuba scene dict of a vkinverse scene file; `overrides` maps material names to
    base colours, or to {field: value} of their inputs, that replace the written
    (reference) ones."""
    overrides = overrides or {}
    film = scene.get("film", {})
    width, height = film.get("width", 256), film.get("height", 256)
    integ = scene.get("integrator", {})
    s = scene["sensors"][sensor]
    d = {
        "type": "scene",
        "integrator": {
            "type": integrator,
            "max_depth": integ.get("max_depth", DEFAULT_MAX_DEPTH),
            "rr_depth": integ.get("rr_depth", DEFAULT_RR_DEPTH),
        },
        "sensor": {
            "type": "perspective",
            # vkinverse's fov_y is the full vertical angle whatever the aspect ratio.
            "fov_axis": "y",
            "fov": s["fov_y"],
            "to_world": _look_at(s["origin"], s["target"], s.get("up", [0, 1, 0])),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {
                "type": "hdrfilm",
                "width": width,
                "height": height,
                "pixel_format": "rgb",
                # vkinverse averages uniformly jittered samples inside each pixel.
                "rfilter": {"type": "box"},
            },
        },
    }
    for m in scene.get("materials", []):
        kind = m.get("type", "diffuse")
        if kind not in ("diffuse", "principled") or (kind == "principled" and not APPROXIMATE):
            fail(f"material {m['name']!r} is {kind!r}: only diffuse materials have an exact Mitsuba counterpart"
                 + (" (--approximate-materials translates principled ones, for timing)" if kind == "principled" else ""))
        inputs = {"base_color": m["base_color"], "metallic": m.get("metallic", 0.0), "roughness": m.get("roughness", 0.5)}
        o = overrides.get(m["name"], {})
        inputs.update(o if isinstance(o, dict) else {"base_color": o})
        for field, v in inputs.items():
            if not isinstance(v, (list, int, float)):
                fail(f"material {m['name']!r}: textured {field} is not translated")
        c = [float(v) for v in inputs["base_color"]]
        if kind == "diffuse":
            brdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": c}}
        else:
            brdf = {"type": "principled", "base_color": {"type": "rgb", "value": c},
                    "metallic": float(inputs["metallic"]), "roughness": float(inputs["roughness"]),
                    # The dielectric part's index (vkinverse's `ior`, Mitsuba's `eta`).
                    "eta": float(m.get("ior", 1.5))}
        # vkinverse shades both sides of every surface (it flips the normal towards the
        # viewer); Mitsuba's BSDFs are one-sided unless wrapped.
        d[mitsuba_key(m["name"])] = {"type": "twosided", "id": mitsuba_key(m["name"]), "brdf_0": brdf}
    for i, mesh in enumerate(scene.get("meshes", [])):
        path = (scene_dir / mesh["file"]).resolve()
        shape = {
            "type": "obj",
            "filename": str(path),
            # Without normals in the file vkinverse shades with the geometric normal;
            # Mitsuba would otherwise smooth normals across the blocks' edges.
            "face_normals": not obj_has_normals(path),
            "bsdf": {"type": "ref", "id": mitsuba_key(mesh["material"])},
        }
        e = mesh.get("emission", [0, 0, 0])
        if any(v > 0 for v in e):
            # Both emit on the counter-clockwise front side only.
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": [float(v) for v in e]}}
        d[f"mesh{i}"] = shape
    env = scene.get("environment")
    if env is not None:
        if env.get("file"):
            fail("environment maps are not translated (only `constant`)")
        c = [float(v) * float(env.get("scale", 1.0)) for v in env.get("constant", [0, 0, 0])]
        d["environment"] = {"type": "constant", "radiance": {"type": "rgb", "value": c}}
    return d


def _look_at(origin, target, up):
    import mitsuba as mi

    return mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up)


# ---------------------------------------------------------------------------------------
# Running vkinverse
# ---------------------------------------------------------------------------------------


def find_vkinverse(arg):
    candidates = []
    if arg:
        candidates.append(Path(arg))
    if os.environ.get("CARGO_TARGET_DIR"):
        candidates.append(Path(os.environ["CARGO_TARGET_DIR"]) / "release" / "vkinverse")
    candidates.append(Path(__file__).resolve().parent.parent / "target" / "release" / "vkinverse")
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    on_path = shutil.which("vkinverse")
    if on_path:
        return Path(on_path)
    fail("no vkinverse release binary found: cargo build --release, or pass --vkinverse PATH")


def run_vk(binary, args, check=True):
    """Runs vkinverse; returns (seconds of wall time, stdout, stderr)."""
    t = time.perf_counter()
    p = subprocess.run([str(binary), *map(str, args)], capture_output=True, text=True)
    dt = time.perf_counter() - t
    if check and p.returncode != 0:
        fail(f"vkinverse {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr.strip()}")
    return dt, p.stdout, p.stderr


def reported_render_time(stderr):
    # "rendered WxH at N spp in T s -> OUT"
    for line in stderr.splitlines():
        if line.startswith("rendered ") and " in " in line:
            try:
                return float(line.split(" in ")[1].split()[0])
            except (IndexError, ValueError):
                pass
    return float("nan")


def per_iteration_time(log_csv):
    """Median wall time between consecutive logged iterations of `vkinverse optimise`."""
    with open(log_csv) as f:
        t = [float(r["time_s"]) for r in csv.DictReader(f)]
    steps = [b - a for a, b in zip(t, t[1:])]
    return statistics.median(steps) if steps else (t[0] if t else float("nan"))


# ---------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------


def mean_se(values):
    n = len(values)
    m = sum(values) / n
    if n < 2:
        return m, float("nan")
    var = sum((v - m) ** 2 for v in values) / (n - 1)
    return m, (var / n) ** 0.5


def mre(np, a, b):
    """Mean relative error between two images (symmetric, floored denominator)."""
    return float(np.mean(np.abs(a - b) / np.maximum(0.5 * (np.abs(a) + np.abs(b)), REL_FLOOR)))


def image_comparison(np, m1, m2, v1, v2):
    """Differences between the renderers against their own noise. Each renderer's
    per-pixel variance is estimated from its two independent renders."""
    out = {
        "mre_mitsuba_vs_vkinverse": mre(np, m1, v1),
        "mre_mitsuba_noise": mre(np, m1, m2),
        "mre_vkinverse_noise": mre(np, v1, v2),
    }
    # If the two agree in expectation, |M1 - V1| has the variance of the two renderers'
    # combined, so its MRE sits between the two noise MREs, near their quadratic mean.
    out["mre_expected_if_equal"] = float(np.sqrt(0.5 * (out["mre_mitsuba_noise"] ** 2 + out["mre_vkinverse_noise"] ** 2)))
    ma, va = 0.5 * (m1 + m2), 0.5 * (v1 + v2)
    var_ma, var_va = 0.25 * (m1 - m2) ** 2, 0.25 * (v1 - v2) ** 2  # unbiased per pixel
    n = m1.shape[0] * m1.shape[1]
    # Image-mean ratio per channel with its standard error (first-order).
    chans = []
    for c in range(3):
        mm, vm = float(ma[..., c].mean()), float(va[..., c].mean())
        se = float(np.sqrt(var_ma[..., c].sum() + var_va[..., c].sum())) / n
        chans.append({"mitsuba": mm, "vkinverse": vm, "diff": mm - vm, "se": se, "z": (mm - vm) / se if se > 0 else float("nan")})
    out["channel_means"] = chans
    # Block z-scores locate systematic differences (the light, shadows, the edges).
    h, w = (m1.shape[0] // BLOCK) * BLOCK, (m1.shape[1] // BLOCK) * BLOCK

    def blocks(x):
        return x[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).sum(axis=(1, 3))

    # A block's variance is the sum of its pixels' only where their noise is independent.
    # A pixel filter wider than the pixel that splats each sample onto its neighbours
    # (Mitsuba's Gaussian) correlates them; each renderer's inflation of the block
    # variance over that sum, measured from its two renders, scales its share (never below
    # 1): per block, (sum of the difference)² over the sum of the squared differences, whose
    # median is 0.455 (that of chi-squared with one degree of freedom) for independent
    # pixels; the median keeps a few fireflies from setting it.
    def inflation(a, b):
        num, den = (blocks(a) - blocks(b)) ** 2, blocks((a - b) ** 2)
        ratios = num[den > 0] / den[den > 0]
        return max(1.0, float(np.median(ratios)) / 0.4549) if ratios.size else 1.0
    infl_m, infl_v = inflation(m1, m2), inflation(v1, v2)
    out["block_variance_inflation"] = {"mitsuba": infl_m, "vkinverse": infl_v}
    diff = blocks(ma - va)
    se = np.sqrt(infl_m * blocks(var_ma) + infl_v * blocks(var_va))
    z = np.where(se > 0, diff / np.where(se > 0, se, 1), 0.0)
    worst = np.unravel_index(int(np.argmax(np.abs(z))), z.shape)
    rel = blocks(ma - va) / np.maximum(blocks(va), 1e-12)
    out["blocks"] = {
        "size": BLOCK,
        "count": int(z.shape[0] * z.shape[1] * 3),
        "abs_z_over_4": int((np.abs(z) > 4).sum()),
        "max_abs_z": float(np.abs(z).max()),
        "worst": {"row": int(worst[0]) * BLOCK, "col": int(worst[1]) * BLOCK, "channel": "rgb"[worst[2]],
                  "z": float(z[worst]), "relative_diff": float(rel[worst])},
    }
    quiet = se < QUIET * np.abs(blocks(va))
    out["blocks"]["noisy"] = {
        "count": int((~quiet).sum()),
        "abs_z_over_4": int(((np.abs(z) > 4) & ~quiet).sum()),
        "max_abs_z": float(np.abs(z)[~quiet].max()) if (~quiet).any() else 0.0,
    }
    out_quiet = (np.abs(z) > 4) & quiet
    out["blocks"]["quiet"] = {
        "count": int(quiet.sum()),
        "abs_z_over_4": int(out_quiet.sum()),
        "median_relative_diff": float(np.median(np.abs(rel[out_quiet]))) if out_quiet.any() else 0.0,
        "max_relative_diff": float(np.abs(rel[out_quiet]).max()) if out_quiet.any() else 0.0,
    }
    out["_z"] = z
    return out


# ---------------------------------------------------------------------------------------
# The three comparisons
# ---------------------------------------------------------------------------------------


def compare_images(np, mi, scene, scene_path, vk, args, out):
    spp = args.spp
    mscene = mi.load_dict(scene_dict(scene, scene_path.parent, "path", spp))

    def mitsuba_render(seed, spp=spp):
        t = time.perf_counter()
        # Reading the image back waits for the render's kernels.
        img = np.array(mi.render(mscene, spp=spp, seed=seed))
        return time.perf_counter() - t, img

    # The first render compiles the kernels (Dr.Jit caches them for later calls); the
    # first vkinverse run fills the driver's shader cache and the file cache.
    cold, _ = mitsuba_render(0)
    v_cold, _, _ = run_vk(vk, ["render", scene_path, "--spp", spp, "--seed", 0, "-o", out / "vk_warmup.exr"])
    # The timed renders alternate between the two, so that a change in the machine's load
    # (other processes) affects both alike; the ratio is also taken per pair.
    m_times, m_imgs = [], []
    v_times, v_reported, v_imgs = [], [], []
    for r in range(args.runs):
        dt, img = mitsuba_render(r + 1)
        m_times.append(dt)
        m_imgs.append(img)
        mi.util.write_bitmap(str(out / f"mitsuba_{spp}spp_seed{r + 1}.exr"), img, write_async=False)
        path = out / f"vkinverse_{spp}spp_seed{r + 1}.exr"
        dt, _, err = run_vk(vk, ["render", scene_path, "--spp", spp, "--seed", r + 1, "-o", path])
        v_times.append(dt)
        v_reported.append(reported_render_time(err))
        v_imgs.append(np.array(mi.Bitmap(str(path)))[..., :3].astype(np.float64))
    # Fixed costs: a 1-spp render of each (Vulkan start-up, pipeline creation, BVH).
    v_one, _, _ = run_vk(vk, ["render", scene_path, "--spp", 1, "--seed", 9, "-o", out / "vk_1spp.exr"])
    m_one = statistics.median(mitsuba_render(9 + r, spp=1)[0] for r in range(3))

    m_imgs = [x.astype(np.float64) for x in m_imgs]
    cmp = image_comparison(np, m_imgs[0], m_imgs[1], v_imgs[0], v_imgs[1])
    z = cmp.pop("_z")
    np.save(out / "block_z.npy", z)
    return {
        "spp": spp,
        "mitsuba_s": statistics.median(m_times),
        "mitsuba_cold_s": cold,
        "mitsuba_1spp_s": m_one,
        "vkinverse_process_s": statistics.median(v_times),
        "vkinverse_reported_s": statistics.median(v_reported),
        "vkinverse_cold_s": v_cold,
        "vkinverse_1spp_process_s": v_one,
        "mitsuba_runs_s": m_times,
        "vkinverse_runs_s": v_times,
        "vkinverse_reported_runs_s": v_reported,
        # Median over the alternating pairs of vkinverse's reported time / Mitsuba's.
        "ratio_reported_per_pair": statistics.median(v / m for v, m in zip(v_reported, m_times)),
        "images": cmp,
        "mitsuba_target": sum(m_imgs) / len(m_imgs),
    }


def scene_with_target(np, mi, scene_path, target, out):
    """A copy of the scene's folder under `out` whose first sensor names `target` (written
    there as an EXR) as its target image, so that vkinverse and Mitsuba differentiate
    against the same image."""
    copy = out / "gradient-scene"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(scene_path.parent, copy, ignore=shutil.ignore_patterns(".vkinverse-cache"))
    mi.util.write_bitmap(str(copy / "compare_target.exr"), target.astype(np.float32), write_async=False)
    lines = (copy / scene_path.name).read_text().splitlines()
    first = next((k for k, l in enumerate(lines) if l.strip() == "[[sensors]]"), None)
    if first is None:
        fail(f"{scene_path}: no [[sensors]] table")
    end = next((k for k in range(first + 1, len(lines)) if lines[k].lstrip().startswith("[")), len(lines))
    body = [l for l in lines[first + 1:end] if not l.strip().startswith("target_image")]
    lines[first + 1:end] = body + ['target_image = "compare_target.exr"']
    (copy / scene_path.name).write_text("\n".join(lines) + "\n")
    return copy / scene_path.name


def compare_gradients(np, dr, mi, scene, scene_path, vk, target, args, out):
    params_vk = color_params(scene)
    spp = args.grad_spp
    # One target for both: it enters the gradient as 2 (I - T) dI, and its own Monte Carlo
    # noise does not average out over rounds, so two renderers with targets of their own
    # would differ by that noise however many rounds each ran.
    compare_scene = scene_with_target(np, mi, scene_path, target, out)
    if args.gradcheck_json:
        # An earlier run's report of the same scene, spp and target (the target is Mitsuba's
        # render with a fixed seed, so it is the same image).
        v_time, stdout = float("nan"), Path(args.gradcheck_json).read_text()
    else:
        v_time, stdout, _ = run_vk(vk, ["gradcheck", compare_scene, "--spp", spp, "--rounds", args.rounds, "--json"], check=False)
    try:
        report = json.loads(stdout)
    except json.JSONDecodeError:
        fail(f"vkinverse gradcheck printed no JSON:\n{stdout}")
    # gradcheck exits non-zero unless its own verdict is "pass"; its numbers are compared
    # here whatever that verdict.
    rows_all = report["rows"] if isinstance(report, dict) else report
    (out / "vkinverse_gradcheck.json").write_text(json.dumps(report, indent=2))

    overrides = {name: init for name, init in params_vk}
    # optimize=False: Mitsuba would otherwise merge materials whose start values are equal
    # (two walls both starting grey) into one, and differentiate them as one parameter.
    mscene = mi.load_dict(scene_dict(scene, scene_path.parent, "prb", spp, overrides=overrides), optimize=False)
    params = mi.traverse(mscene)
    keys = [f"{mitsuba_key(name)}.brdf_0.reflectance.value" for name, _ in params_vk]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    target_t = mi.TensorXf(target.astype(np.float32))

    def estimate(seed):
        t = time.perf_counter()
        img = mi.render(mscene, params, spp=spp, spp_grad=spp, seed=seed)
        loss = dr.mean(dr.square(img - target_t), axis=None)
        dr.backward(loss)
        # Reading the gradients back waits for the adjoint pass's kernels.
        g = [np.array(dr.grad(params[key])).ravel()[:3].astype(np.float64) for key in keys]
        dr.sync_thread()
        dt = time.perf_counter() - t
        for key in keys:
            dr.set_grad(params[key], 0)
        return dt, g

    estimate(10_000)  # kernel compilation
    m_times, m_grads = [], []
    # Seeds far apart: Mitsuba derives the adjoint phase's seed from the primal one, and
    # rounds on neighbouring seeds could share samples (and understate the spread).
    for r in range(args.mitsuba_rounds):
        dt, g = estimate(7919 * (r + 1))
        m_times.append(dt)
        m_grads.append(g)

    # One gradient estimate at the same sample counts: an Adam iteration's time, which is
    # primal + loss + adjoint and an optimiser pass of the parameters.
    est_dir = out / "vk_grad_timing"
    shutil.rmtree(est_dir, ignore_errors=True)
    run_vk(vk, ["optimise", scene_path, "--optimiser", "adam", "--iterations", args.rounds + 2,
                "--spp", spp, "--primal-spp", spp, "--quiet", "-o", est_dir])
    v_est = per_iteration_time(est_dir / "log.csv")

    def z(a, sa, b, sb):
        se = (sa * sa + sb * sb) ** 0.5
        return (a - b) / se if se > 0 else float("nan")

    result = {"spp": spp, "rounds": report.get("rounds", args.rounds) if isinstance(report, dict) else args.rounds,
              "mitsuba_rounds": args.mitsuba_rounds, "vkinverse_verdict": report.get("verdict") if isinstance(report, dict) else None,
              "params": []}
    for p, (name, init) in enumerate(params_vk):
        target_name = f"materials.{name}.base_color"
        rows = sorted((r for r in rows_all if r["param"] == target_name), key=lambda r: r["element"])
        if len(rows) != 3:
            fail(f"vkinverse gradcheck reported {len(rows)} elements of {target_name}, expected 3")
        channels = []
        for c in range(3):
            mm, ms = mean_se([g[p][c] for g in m_grads])
            va, vas = rows[c]["adjoint"], rows[c]["adjoint_se"]
            vf, vfs = rows[c]["finite_difference"], rows[c]["finite_difference_se"]
            channels.append({
                "mitsuba": mm, "mitsuba_se": ms,
                "vkinverse": va, "vkinverse_se": vas,
                "vkinverse_fd": vf, "vkinverse_fd_se": vfs,
                "z_mitsuba_adjoint": z(mm, ms, va, vas),
                "z_mitsuba_fd": z(mm, ms, vf, vfs),
                "z_adjoint_fd": z(va, vas, vf, vfs),
            })
        result["params"].append({"param": target_name, "init": init, "channels": channels})
    result["mitsuba_per_estimate_s"] = statistics.median(m_times)
    result["vkinverse_per_estimate_s"] = v_est
    result["vkinverse_gradcheck_process_s"] = v_time
    return result


def compare_optimisation(np, dr, mi, scene, scene_path, vk, target, args, out):
    # Every optimised constant input that has a Mitsuba parameter, at the first one's rate
    # (vkinverse runs with --lr, which replaces the scene's per-parameter rates).
    inputs = opt_params(scene)
    if not inputs:
        fail("the scene optimises no constant material input that part c translates "
             "(a base colour, or a principled material's metallic or roughness)")
    opt_cfg = scene.get("optimise", {})
    lr = inputs[0][4] if inputs[0][4] is not None else opt_cfg.get("lr", 0.02)
    spp = args.opt_spp or opt_cfg.get("spp", 2)
    primal_spp = args.opt_primal_spp or opt_cfg.get("primal_spp", 4)
    iters = args.iterations
    overrides = {}
    for name, field, init, _, _, _ in inputs:
        overrides.setdefault(name, {})[field] = init
    mscene = mi.load_dict(scene_dict(scene, scene_path.parent, "prb", primal_spp, overrides=overrides))
    params = mi.traverse(mscene)
    keys = [(key, rng) for _, _, _, rng, _, key in inputs]
    target_t = mi.TensorXf(target.astype(np.float32))
    opt = mi.ad.Adam(lr=lr)
    for key, _ in keys:
        opt[key] = params[key]
    params.update(opt)

    times = []

    def mitsuba_iterations(first, count):
        for it in range(first, first + count):
            t = time.perf_counter()
            # Primal image at primal_spp; the adjoint pass replays spp samples per pixel,
            # as vkinverse's primal_spp / spp do.
            img = mi.render(mscene, params, spp=primal_spp, spp_grad=spp, seed=it)
            loss = dr.mean(dr.square(img - target_t), axis=None)
            dr.backward(loss)
            opt.step()
            for key, rng in keys:
                opt[key] = dr.clip(opt[key], rng[0], rng[1])
            params.update(opt)
            # The step and the optimiser state are evaluated inside the iteration (else
            # their kernels would run lazily in the next one), and the loss is read back
            # as vkinverse's is; then every launched kernel is waited for.
            dr.eval(*[params[key] for key, _ in keys], *[opt[key] for key, _ in keys])
            loss_value = float(np.array(loss).ravel()[0])
            dr.sync_thread()
            times.append(time.perf_counter() - t)
            del loss_value

    opt_dir = out / "vk_adam"
    shutil.rmtree(opt_dir, ignore_errors=True)
    vk_args = [str(vk), "optimise", str(scene_path), "--optimiser", "adam", "--iterations", str(iters), "--spp",
               str(spp), "--primal-spp", str(primal_spp), "--lr", str(lr), "--quiet", "-o", str(opt_dir)]
    if args.concurrent:
        # Both at once, one thread each (Dr.Jit's pool and lavapipe's rasterizer threads),
        # so that whatever else loads the machine slows both alike. Mitsuba's kernels are
        # compiled first; its iterations count while vkinverse's process runs.
        previous_threads = dr.thread_count()
        dr.set_thread_count(1)
        mitsuba_iterations(0, 3)
        del times[:]
        t = time.perf_counter()
        proc = subprocess.Popen(vk_args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "LP_NUM_THREADS": "1"})
        it = 3
        while proc.poll() is None:
            mitsuba_iterations(it, 1)
            it += 1
        _, err = proc.communicate()
        wall = time.perf_counter() - t
        # Mitsuba kept iterating while vkinverse ran: its result is after `it` iterations.
        m_iterations = it
        dr.set_thread_count(previous_threads)
        if proc.returncode != 0:
            fail(f"vkinverse {' '.join(vk_args[1:])} failed ({proc.returncode}):\n{err.strip()}")
        # Mitsuba's last iteration may have run partly alone.
        if len(times) > 2:
            times.pop()
    else:
        # Half of Mitsuba's iterations before vkinverse's run and half after, so that a
        # change in the machine's load shows in both medians.
        mitsuba_iterations(0, iters // 2)
        wall, _, _ = run_vk(vk, vk_args[1:])
        mitsuba_iterations(iters // 2, iters - iters // 2)
        m_iterations = iters
    # The first optimised input's result, as a vector.
    as_vector = lambda v: v if isinstance(v, list) or v is None else [v]
    name, field, init, _, _, _ = inputs[0]
    init = as_vector(init)
    m_final = np.array(params[keys[0][0]]).ravel()[:3].tolist()
    summary = json.loads((opt_dir / "summary.json").read_text())
    v_final = as_vector(json.loads((opt_dir / "params" / "params.json").read_text()).get(f"materials.{name}.{field}"))
    reference = as_vector(next(m.get(field) for m in scene["materials"] if m["name"] == name))
    return {
        "iterations": iters, "spp": spp, "primal_spp": primal_spp, "lr": lr,
        "concurrent": bool(args.concurrent),
        "mitsuba_iterations": m_iterations,
        # The first iterations compile Dr.Jit's kernels; the median leaves them out (the
        # concurrent mode ran them before timing).
        "mitsuba_per_iter_s": statistics.median(
            times if args.concurrent or iters < 8 else times[min(3, iters // 2 - 1):]),
        "mitsuba_first_iter_s": times[0],
        "vkinverse_per_iter_s": per_iteration_time(opt_dir / "log.csv"),
        "vkinverse_mean_iter_s": summary["total_time_s"] / max(summary["iterations"], 1),
        "vkinverse_process_s": wall,
        "reference": reference, "init": init, "mitsuba_final": m_final, "vkinverse_final": v_final,
        "input": f"materials.{name}.{field}", "inputs": [f"materials.{n}.{f}" for n, f, _, _, _, _ in inputs],
    }


# ---------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------


def fmt_vec(v):
    return "[" + ", ".join(f"{x:.4f}" for x in v) + "]" if v else "n/a"


def print_tables(a, b, c):
    print(f"\n(a) images at {a['spp']} spp" if a else "")
    if a:
        im = a["images"]
        if APPROXIMATE:
            print("  (--approximate-materials: Mitsuba renders another principled model, so the image "
                  "comparison below measures the models' difference, not an error)")
        print(f"  {'':34} {'Mitsuba':>10} {'vkinverse':>10} {'ratio vk/mi':>12}")
        print(f"  {'render, median wall s (warm)':34} {a['mitsuba_s']:10.3f} {a['vkinverse_process_s']:10.3f} {a['vkinverse_process_s'] / a['mitsuba_s']:12.2f}")
        print(f"  {'  vkinverse self-reported s':34} {'':10} {a['vkinverse_reported_s']:10.3f} {a['vkinverse_reported_s'] / a['mitsuba_s']:12.2f}")
        print(f"  {'  per alternating pair, median':34} {'':10} {'':10} {a['ratio_reported_per_pair']:12.2f}")
        print(f"  {'1 spp (fixed costs) s':34} {a['mitsuba_1spp_s']:10.3f} {a['vkinverse_1spp_process_s']:10.3f}")
        print(f"  {'first (cold) render s':34} {a['mitsuba_cold_s']:10.3f} {a['vkinverse_cold_s']:10.3f}")
        print(f"  mean relative error: Mitsuba vs vkinverse {im['mre_mitsuba_vs_vkinverse']:.4f}; "
              f"noise: Mitsuba {im['mre_mitsuba_noise']:.4f}, vkinverse {im['mre_vkinverse_noise']:.4f} "
              f"(expected if equal {im['mre_expected_if_equal']:.4f})")
        for ch, cm in zip("RGB", im["channel_means"]):
            print(f"  mean {ch}: Mitsuba {cm['mitsuba']:.5f}  vkinverse {cm['vkinverse']:.5f}  "
                  f"diff {cm['diff']:+.5f} ± {cm['se']:.5f} (z {cm['z']:+.1f})")
        bl = im["blocks"]
        w = bl["worst"]
        print(f"  {bl['size']}x{bl['size']} blocks with |z| > 4: {bl['abs_z_over_4']} of {bl['count']}; worst at "
              f"row {w['row']} col {w['col']} {w['channel']}: z {w['z']:+.1f}, {100 * w['relative_diff']:+.2f}%")
    if b:
        print(f"\n(b) d(l2 loss)/d colour at its init, {b['spp']} spp, mean ± se of {b['mitsuba_rounds']} (Mitsuba) and "
              f"{b['rounds']} (vkinverse) rounds, one target; z = difference / combined se "
              f"(vkinverse gradcheck's own verdict: {b['vkinverse_verdict']})")
        print(f"  {'param':28} {'ch':2} {'Mitsuba prb':>22} {'vkinverse adjoint':>22} {'z mi-adj':>8} "
              f"{'vkinverse FD':>22} {'z mi-fd':>7} {'z adj-fd':>8}")
        for p in b["params"]:
            for ch, g in zip("RGB", p["channels"]):
                print(f"  {p['param']:28} {ch:2} {g['mitsuba']:+11.4e} ± {g['mitsuba_se']:8.2e} "
                      f"{g['vkinverse']:+11.4e} ± {g['vkinverse_se']:8.2e} {g['z_mitsuba_adjoint']:+8.2f} "
                      f"{g['vkinverse_fd']:+11.4e} ± {g['vkinverse_fd_se']:8.2e} {g['z_mitsuba_fd']:+7.2f} {g['z_adjoint_fd']:+8.2f}")
        print(f"  time per gradient estimate: Mitsuba {b['mitsuba_per_estimate_s']:.3f} s, vkinverse "
              f"{b['vkinverse_per_estimate_s']:.3f} s (ratio vk/mi {b['vkinverse_per_estimate_s'] / b['mitsuba_per_estimate_s']:.2f}); "
              f"whole vkinverse gradcheck process {b['vkinverse_gradcheck_process_s']:.2f} s")
    if c:
        mode = ", concurrent, one thread each" if c.get("concurrent") else ""
        print(f"\n(c) Adam, {c['iterations']} iterations, spp {c['spp']} (primal {c['primal_spp']}), lr {c['lr']}{mode}")
        print(f"  time per iteration: Mitsuba {c['mitsuba_per_iter_s']:.4f} s (first {c['mitsuba_first_iter_s']:.2f} s), "
              f"vkinverse {c['vkinverse_per_iter_s']:.4f} s (mean {c['vkinverse_mean_iter_s']:.4f} s); "
              f"ratio vk/mi {c['vkinverse_per_iter_s'] / c['mitsuba_per_iter_s']:.2f}")
        print(f"  optimised: {', '.join(c['inputs'])}")
        print(f"  {c['input']}: reference {fmt_vec(c['reference'])}, init {fmt_vec(c['init'])}, "
              f"Mitsuba {fmt_vec(c['mitsuba_final'])} (after {c.get('mitsuba_iterations', c['iterations'])} iterations), "
              f"vkinverse {fmt_vec(c['vkinverse_final'])} (after {c['iterations']})")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path, help="vkinverse scene.toml")
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel of the image comparison")
    ap.add_argument("--runs", type=int, default=3, help="timed renders of each (at least 2: the noise needs two)")
    ap.add_argument("--grad-spp", type=int, default=16, help="samples per pixel of each gradient estimate")
    ap.add_argument("--rounds", type=int, default=8, help="independent gradient estimates of vkinverse (gradcheck rounds)")
    ap.add_argument("--mitsuba-rounds", type=int, default=128, help="independent gradient estimates of Mitsuba (cheap)")
    ap.add_argument("--gradcheck-json", help="part b: take vkinverse's side from this earlier `gradcheck --json` report "
                    "(OUT/vkinverse_gradcheck.json of a run with the same scene, --spp, --grad-spp and --rounds)")
    ap.add_argument("--iterations", type=int, default=50, help="Adam iterations of each")
    ap.add_argument("--opt-spp", type=int, help="adjoint spp per iteration (default: the scene's)")
    ap.add_argument("--opt-primal-spp", type=int, help="primal spp per iteration (default: the scene's)")
    ap.add_argument("--concurrent", action="store_true",
                    help="part c: run Mitsuba's and vkinverse's iterations at the same time, one thread each "
                    "(LP_NUM_THREADS=1, Dr.Jit's thread count 1), so that the machine's load affects both alike")
    ap.add_argument("--parts", default="abc", help="which comparisons to run (subset of abc)")
    ap.add_argument("--res", help="comma-separated film sizes (square) to run everything at, e.g. 64,256 "
                    "(default: the scene's own film)")
    ap.add_argument("--vkinverse", help="vkinverse binary (default: $CARGO_TARGET_DIR or target/ release build)")
    ap.add_argument("--out", type=Path, required=True, help="directory for images, logs and results.json")
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["llvm_ad_rgb", "cuda_ad_rgb"],
                    help="Mitsuba's variant (default: %(default)s)")
    ap.add_argument("--approximate-materials", action="store_true",
                    help="translate principled materials to Mitsuba's principled BSDF, a different model: "
                    "for timing (parts a and c), not for comparing images or gradients")
    args = ap.parse_args()
    set_variant(args.variant)
    global APPROXIMATE
    APPROXIMATE = args.approximate_materials
    if APPROXIMATE and "b" in args.parts:
        fail("--approximate-materials: part b compares gradients, which needs the same model on both sides; "
             "run --parts ac")
    if args.runs < 2:
        fail("--runs must be at least 2")
    if args.rounds < 2:
        fail("--rounds must be at least 2")

    np, dr, mi = import_mitsuba()
    vk = find_vkinverse(args.vkinverse)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    if not args.res:
        scene_path = args.scene.resolve()
        results = run_all(np, dr, mi, scene_path, vk, args, out)
        (out / "results.json").write_text(json.dumps(results, indent=2))
        print(f"\nresults.json and images in {out}")
        return
    try:
        sizes = [int(r) for r in args.res.split(",")]
    except ValueError:
        fail(f"--res {args.res!r}: expected comma-separated integers, e.g. 64,256")
    if any(r < 8 for r in sizes):
        fail("--res: sizes must be at least 8")
    by_res = {}
    for r in sizes:
        res_out = out / f"res-{r}"
        res_out.mkdir(parents=True, exist_ok=True)
        scene_path = scene_at_resolution(args.scene.resolve(), r, res_out)
        by_res[r] = run_all(np, dr, mi, scene_path, vk, args, res_out)
        (res_out / "results.json").write_text(json.dumps(by_res[r], indent=2))
    print_ratios(args.scene, by_res)
    (out / "results.json").write_text(json.dumps({str(r): v for r, v in by_res.items()}, indent=2))
    print(f"\nresults.json per resolution in {out}/res-N/, all in {out}/results.json")


def scene_at_resolution(scene_path, res, out):
    """A copy of the scene's folder under `out` whose [film] is res x res."""
    copy = out / "scene"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(scene_path.parent, copy, ignore=shutil.ignore_patterns(".vkinverse-cache"))
    lines = (copy / scene_path.name).read_text().splitlines()
    film = next((k for k, l in enumerate(lines) if l.strip() == "[film]"), None)
    if film is None:
        lines[:0] = ["[film]", f"width = {res}", f"height = {res}", ""]
    else:
        end = next((k for k in range(film + 1, len(lines)) if lines[k].lstrip().startswith("[")), len(lines))
        body = [l for l in lines[film + 1:end] if l.split("=")[0].strip() not in ("width", "height")]
        lines[film + 1:end] = [f"width = {res}", f"height = {res}"] + body
    (copy / scene_path.name).write_text("\n".join(lines) + "\n")
    return copy / scene_path.name


def run_all(np, dr, mi, scene_path, vk, args, out):
    """Parts a, b and c (as selected) on one scene file; prints their tables."""
    scene = load_toml(scene_path)
    a = b = c = None
    target = None
    if "a" in args.parts:
        a = compare_images(np, mi, scene, scene_path, vk, args, out)
        target = a.pop("mitsuba_target")
    if target is None and ("b" in args.parts or "c" in args.parts):
        # Mitsuba's own high-spp render of the reference scene is its target, as
        # vkinverse renders its own.
        ms = mi.load_dict(scene_dict(scene, scene_path.parent, "path", args.spp))
        target = np.array(mi.render(ms, spp=args.spp, seed=12345)).astype(np.float64)
    if "b" in args.parts:
        b = compare_gradients(np, dr, mi, scene, scene_path, vk, target, args, out)
    if "c" in args.parts:
        c = compare_optimisation(np, dr, mi, scene, scene_path, vk, target, args, out)

    film = scene.get("film", {})
    print(f"Mitsuba {mi.__version__} ({VARIANT}) vs {vk}; scene {scene_path} "
          f"({film.get('width', 256)}x{film.get('height', 256)})")
    print_tables(a, b, c)
    return {"images": a, "gradient": b, "optimisation": c}


def print_ratios(scene, by_res):
    """One line per resolution: the time ratios vkinverse / Mitsuba."""
    print(f"\ntime ratios vkinverse / Mitsuba ({VARIANT}), {scene}")
    print(f"  {'res':>5} {'render (pairs)':>18} {'render (process)':>17} {'gradient':>9} {'Adam iter':>10} "
          f"{'Adam ms vk / mi':>16}")
    for r, v in by_res.items():
        a, b, c = v["images"], v["gradient"], v["optimisation"]
        ra = a["ratio_reported_per_pair"] if a else float("nan")
        rp = a["vkinverse_process_s"] / a["mitsuba_s"] if a else float("nan")
        rb = b["vkinverse_per_estimate_s"] / b["mitsuba_per_estimate_s"] if b else float("nan")
        rc = c["vkinverse_per_iter_s"] / c["mitsuba_per_iter_s"] if c else float("nan")
        ms = f"{1e3 * c['vkinverse_per_iter_s']:.1f} / {1e3 * c['mitsuba_per_iter_s']:.1f}" if c else "n/a"
        print(f"  {r:>5} {ra:>18.2f} {rp:>17.2f} {rb:>9.2f} {rc:>10.2f} {ms:>16}")


if __name__ == "__main__":
    main()
