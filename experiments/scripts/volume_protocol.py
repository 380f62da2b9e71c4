#!/usr/bin/env python3
"""The volume experiment of experiments/volume.md on scenes/smoke (or, with --scene, another
medium scene beside its heldout.toml, such as scenes/cloud): held-out image error and grid
error of recovered media, and the three arms run at equal iterations and equal time.
Needs numpy and a built binary (target/release/vkinverse, or --bin).

    python3 experiments/scripts/volume_protocol.py eval RUNDIR [RUNDIR ...]
    python3 experiments/scripts/volume_protocol.py run OUTDIR [--scene S] [--iterations N] [--film WxH] [--adam-lr X]
    python3 experiments/scripts/volume_protocol.py report OUTDIR

`eval` reads finished runs of `vkinverse optimise scenes/smoke/scene.toml -o RUNDIR`. For each
it writes RUNDIR/heldout/scene.toml, scenes/smoke/heldout.toml with the run's recovered
grids (RUNDIR/final/grids/) in place of the true ones, renders every held-out view of it
and of the true medium (RUNDIR/heldout/recovered-K.npy, true-K.npy; the same seed for both),
and reports
- the held-out MAPE, mean |x - y| / (|y| + 0.01) over every pixel, channel and held-out view
  (x the recovered medium's image, y the true one's), and the same over the smoke's pixels
  alone (those where the true image exceeds twice the constant sky in some channel);
- the density's and the emission's RMSE against the true grids (a recovered grid of another
  resolution resampled to the true one's, trilinear between voxel centres as the kernels
  look it up);
- the run's iterations, its optimisation time (log.csv's `time_s`) and seconds per
  iteration;
- in eval.json only: the training views' image error (summary.json's `final_image_error`
  and `reference_image_error`) and the training loss (the mean of log.csv's `loss` over
  the run's last fifth; meta's is its carried image's, less noisy than a fresh render's,
  so it does not compare with Adam's).
The figures go to RUNDIR/heldout/eval.json and one table row per run to stdout. The views
render at the run's film (summary.json) unless --film is given, at --spp samples (64).

`run` runs the three arms into OUTDIR/ARM (each `vkinverse optimise` with the scene's other
settings; --adam-lr, --film and --iterations apply to every arm where they apply):
- adam2: Adam at 2 spp (primal images at 2 spp), at --adam-lr;
- meta:  the meta-estimator (spec `meta`) at 2 spp + 1 finite-difference spp, primal images
         at 2 spp, at the scene's rate;
- adam4: Adam at 4 spp (primal images at 4 spp), at --adam-lr.
Adam at 2 spp, the cheapest, runs first for N iterations; the time its log.csv gives for
them is the equal-time budget T. Each other arm first runs with --time-budget T (it stops
at the last iteration that ends within T, by log.csv's time) and is evaluated there, then
continues with --resume to N iterations and is evaluated again: one run per arm yields
both comparisons (the stopped run's heldout/, params/ and summary.json are kept in
OUTDIR/ARM-at-time). Last, the meta arm runs again from the start into OUTDIR/meta-half,
with --time-budget half of Adam at 4 spp's time for N iterations, and is evaluated there:
the issue's goal is that it reaches Adam at 4 spp's final held-out MAPE by then. The
tables go to stdout and OUTDIR/volume.md, the figures to OUTDIR/volume.json; `report`
prints the tables of OUTDIR/volume.json again.
"""

import argparse
import csv
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "smoke" / "scene.toml"
HELDOUT = ROOT / "scenes" / "smoke" / "heldout.toml"
BIN = ROOT / "target" / "release" / "vkinverse"
# The MAPE's offset in the denominator, |x - y| / (|y| + EPS).
EPS = 0.01

# The arms: name, label, optimise flags (ADAM_LR stands for --adam-lr). The first is the
# cheapest: its time for N iterations is the equal-time budget.
ARMS = [
    ("adam2", "Adam, 2 spp", ["--optimiser", "adam", "--spp", "2", "--primal-spp", "2", "--lr", "ADAM_LR"]),
    ("meta", "meta, 2 spp + 1 FD", ["--optimiser", "meta", "--spp", "2", "--fd-spp", "1", "--primal-spp", "2"]),
    ("adam4", "Adam, 4 spp", ["--optimiser", "adam", "--spp", "4", "--primal-spp", "4", "--lr", "ADAM_LR"]),
]


def vk(args, bin_path):
    cmd = [str(bin_path), *map(str, args)]
    print("$ " + " ".join(cmd), file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True)


def log_rows(run):
    with open(run / "log.csv", newline="") as f:
        return list(csv.DictReader(f))


def media_grids(scene_path):
    """The density and emission values of a scene file's medium: paths resolved against
    the scene's folder, numbers as they are."""
    m = tomllib.loads(scene_path.read_text())["media"][0]
    resolve = lambda v: (scene_path.parent / v).resolve() if isinstance(v, str) else v  # noqa: E731
    return resolve(m["density"]), resolve(m.get("emission", 0.0))


def as_grid(value, channels):
    """A grid [z, y, x, channels] from a `.npy` path or a constant."""
    if isinstance(value, Path):
        a = np.load(value).astype(np.float64)
        return a.reshape(*a.shape[:3], channels)
    return np.broadcast_to(np.asarray(value, dtype=np.float64).reshape(-1)[:channels], (1, 1, 1, channels))


def resample(grid, shape):
    """`grid` [z, y, x, c] at `shape`'s [z, y, x] voxel centres: trilinear between the
    source's voxel centres, clamped at its faces (src/scene/media.rs `resample`)."""
    out = grid
    for axis, n in enumerate(shape):
        src = out.shape[axis]
        if src == n:
            continue
        p = np.clip((np.arange(n) + 0.5) / n * src - 0.5, 0.0, src - 1)
        lo = np.floor(p).astype(int)
        hi = np.minimum(lo + 1, src - 1)
        t = (p - lo).reshape([-1 if a == axis else 1 for a in range(out.ndim)])
        out = np.take(out, lo, axis=axis) * (1 - t) + np.take(out, hi, axis=axis) * t
    return out


def rmse(recovered, true):
    """The RMSE of grid `recovered` against grid `true` (either may be a constant), at the
    true grid's resolution."""
    if true.shape[:3] != (1, 1, 1):
        recovered = resample(recovered, true.shape[:3])
    return float(np.sqrt(np.mean((recovered - true) ** 2)))


def heldout_scene(run, heldout):
    """Writes RUNDIR/heldout/scene.toml: the held-out scene with the run's recovered grids,
    and returns its path."""
    density, emission = media_grids(run / "final" / "scene.toml")
    out = run / "heldout"
    out.mkdir(exist_ok=True)
    text = heldout.read_text()

    def value(v):
        if isinstance(v, Path):
            return json.dumps(Path(os.path.relpath(v, out)).as_posix())
        return json.dumps(v)

    for key, v in (("density", density), ("emission", emission)):
        text, n = re.subn(rf"^{key} = .*$", lambda _: f"{key} = {value(v)}", text, count=1, flags=re.M)
        # A scattering medium has no emission line: nothing was recovered there.
        assert n == 1 or key == "emission", f"{heldout} has no `{key} = ` line"
    path = out / "scene.toml"
    path.write_text(f"# {heldout.name} with the recovered grids of {run.name}.\n" + text)
    return path


def evaluate(run, heldout=HELDOUT, film=None, spp=64, seed=0, bin_path=BIN):
    """The held-out and grid errors of a finished run (see the module's doc)."""
    run = Path(run)
    summary = json.loads((run / "summary.json").read_text())
    film = film or "x".join(map(str, summary["film"]))
    scene = heldout_scene(run, heldout)
    held = tomllib.loads(heldout.read_text())
    sensors = len(held["sensors"])
    sky = held.get("environment", {}).get("constant")
    threshold = 2 * max(sky) if sky else 0.0
    num = den = 0.0
    errors, smoke = [], []
    for k in range(sensors):
        images = {}
        for which, path in (("true", heldout), ("recovered", scene)):
            file = run / "heldout" / f"{which}-{k}.npy"
            vk(["render", path, "--sensor", k, "--spp", spp, "--seed", seed, "--film", film, "--quiet", "-o", file], bin_path)
            images[which] = np.load(file).astype(np.float64)
        x, y = images["recovered"], images["true"]
        ape = np.abs(x - y) / (np.abs(y) + EPS)
        errors.append(float(ape.mean()))
        smoke.append(ape[np.max(y, axis=-1) > threshold])
        num += ape.sum()
        den += ape.size
    true_d, true_e = media_grids(heldout)
    rec_d, rec_e = media_grids(run / "final" / "scene.toml")
    rows = log_rows(run)
    losses = [float(r["loss"]) for r in rows[1:] if r["loss"]]
    tail = losses[len(losses) - max(1, len(losses) // 5) :]
    iterations = int(rows[-1]["iteration"])
    time_s = float(rows[-1]["time_s"])
    result = {
        "run": str(run),
        "optimiser": summary["optimiser"],
        "settings": summary["settings"],
        "film": film,
        "iterations": iterations,
        "time_s": time_s,
        "s_per_iteration": time_s / max(iterations, 1),
        "train_loss": sum(tail) / len(tail) if tail else None,
        "train_image_error": summary.get("final_image_error"),
        "train_reference_image_error": summary.get("reference_image_error"),
        "heldout_mape": num / den,
        "heldout_mape_per_view": errors,
        "heldout_mape_smoke": float(np.concatenate(smoke).mean()),
        "heldout_smoke_pixels": sum(len(a) for a in smoke),
        "density_rmse": rmse(as_grid(rec_d, 1), as_grid(true_d, 1)),
        "emission_rmse": rmse(as_grid(rec_e, 3), as_grid(true_e, 3)),
        "eval_spp": spp,
    }
    (run / "heldout" / "eval.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


HEADER = (
    "| run | iterations | time (s) | s / iteration | held-out MAPE | held-out MAPE, smoke pixels | density RMSE | emission RMSE |\n"
    "|---|---|---|---|---|---|---|---|"
)


def row(label, r):
    return (
        f"| {label} | {r['iterations']} | {r['time_s']:.0f} | {r['s_per_iteration']:.2f} "
        f"| {r['heldout_mape']:.4f} | {r['heldout_mape_smoke']:.4f} | {r['density_rmse']:.4f} | {r['emission_rmse']:.4f} |"
    )


def tables(results):
    """The equal-iteration and equal-time tables of a `run`'s figures."""
    n, film = results["iterations"], results["film"] or "the scene's"
    lines = [
        f"Equal iterations ({n}, film {film}, Adam's rate {results['adam_lr']}):\n",
        HEADER,
        *(row(a["label"], a["equal_iterations"]) for a in results["arms"].values()),
        f"\nEqual time ({results['time_budget_s']:.0f} s, Adam at 2 spp's time for {n} iterations):\n",
        HEADER,
        *(row(a["label"], a["equal_time"]) for a in results["arms"].values()),
    ]
    half = results.get("meta_half")
    if half:
        final = results["arms"]["adam4"]["equal_iterations"]
        lines += [
            f"\nMeta in half of Adam at 4 spp's time ({half['budget_s']:.0f} s of {final['time_s']:.0f} s):\n",
            HEADER,
            row("Adam, 4 spp (final)", final),
            row("meta, 2 spp + 1 FD", half["result"]),
            f"\nMeta {'reaches' if half['reached'] else 'does not reach'} Adam at 4 spp's final held-out MAPE "
            f"({half['result']['heldout_mape']:.4f} against {final['heldout_mape']:.4f}).",
        ]
    return "\n".join(lines) + "\n"


def run_arms(args):
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    common = ["--iterations", args.iterations, "--seed", args.seed] + (["--film", args.film] if args.film else [])
    results = {"iterations": args.iterations, "film": args.film, "adam_lr": args.adam_lr, "arms": {}}
    budget = None
    for name, label, flags in ARMS:
        flags = [args.adam_lr if f == "ADAM_LR" else f for f in flags]
        run = out / name
        base = ["optimise", args.scene, "-o", run, "--quiet", *flags, *common]
        arm = results["arms"][name] = {"label": label}
        if budget is None:
            vk(base + ["--overwrite"], args.bin)
            arm["equal_iterations"] = arm["equal_time"] = evaluate(run, heldout=args.scene.parent / "heldout.toml", spp=args.spp, bin_path=args.bin)
            budget = arm["equal_time"]["time_s"]
            results["time_budget_s"] = budget
            continue
        vk(base + ["--overwrite", "--time-budget", f"{budget:.3f}"], args.bin)
        arm["equal_time"] = evaluate(run, heldout=args.scene.parent / "heldout.toml", spp=args.spp, bin_path=args.bin)
        at_time = out / f"{name}-at-time"
        shutil.rmtree(at_time, ignore_errors=True)
        shutil.copytree(run / "heldout", at_time / "heldout")
        shutil.copytree(run / "params", at_time / "params")
        shutil.copy(run / "summary.json", at_time / "summary.json")
        vk(base + ["--resume"], args.bin)
        arm["equal_iterations"] = evaluate(run, heldout=args.scene.parent / "heldout.toml", spp=args.spp, bin_path=args.bin)
    # Meta again from the start, in half of Adam at 4 spp's time for the N iterations.
    final = results["arms"]["adam4"]["equal_iterations"]
    half_budget = final["time_s"] / 2
    name, label, flags = next(a for a in ARMS if a[0] == "meta")
    run = out / "meta-half"
    vk(["optimise", args.scene, "-o", run, "--quiet", *flags, *common, "--overwrite", "--time-budget", f"{half_budget:.3f}"], args.bin)
    half = evaluate(run, heldout=args.scene.parent / "heldout.toml", spp=args.spp, bin_path=args.bin)
    results["meta_half"] = {"budget_s": half_budget, "result": half, "reached": bool(half["heldout_mape"] <= final["heldout_mape"])}
    (out / "volume.json").write_text(json.dumps(results, indent=1) + "\n")
    text = tables(results)
    (out / "volume.md").write_text(text)
    print(text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bin", type=Path, default=BIN, help="the vkinverse binary")
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel of the held-out renders")
    sub = parser.add_subparsers(dest="mode", required=True)
    ev = sub.add_parser("eval", help="held-out MAPE and grid RMSE of finished runs")
    ev.add_argument("runs", nargs="+", type=Path)
    ev.add_argument("--film", help="WxH of the held-out renders (default: each run's film)")
    ev.add_argument("--heldout", type=Path, default=HELDOUT, help="the held-out scene (default: scenes/smoke/heldout.toml)")
    rn = sub.add_parser("run", help="the three arms at equal iterations and equal time")
    rn.add_argument("outdir")
    rn.add_argument("--scene", type=Path, default=SCENE, help="the scene (default: scenes/smoke/scene.toml); its heldout.toml beside it")
    rn.add_argument("--iterations", type=int, default=500)
    rn.add_argument("--film", help="WxH (default: the scene's)")
    rn.add_argument("--adam-lr", default="0.02", help="Adam's learning rate")
    rn.add_argument("--seed", type=int, default=0)
    rp = sub.add_parser("report", help="the tables of a `run`'s OUTDIR/volume.json")
    rp.add_argument("outdir", type=Path)
    args = parser.parse_args()
    if args.mode == "eval":
        print(HEADER)
        for run in args.runs:
            print(row(run.name, evaluate(run, heldout=args.heldout, film=args.film, spp=args.spp, bin_path=args.bin)), flush=True)
    elif args.mode == "report":
        print(tables(json.loads((args.outdir / "volume.json").read_text())), end="")
    else:
        run_arms(args)


if __name__ == "__main__":
    sys.exit(main())
