#!/usr/bin/env python3
"""Runs a job file at several seeds, each scene's jobs at each seed as one `vkinverse batch`,
several batches at once (standard library only). On a machine with many cores and one GPU
the batches overlap their CPU work (scene loading, targets, plots) with each other's GPU
work: pilot 47's 672 jobs took about 3 minutes on an H100 with 10 at once.

    python3 experiments/scripts/batch_seeds.py JOBFILE OUTDIR SEED [SEED ...] [--scene NAME]... [--parallel N] [--bin PATH] [-- BATCH_ARGS...]
    python3 experiments/scripts/batch_seeds.py experiments/pilots/pilot47.toml out/pilot47 0 1 2 3 4 5 6 7 --parallel 10

Each batch writes OUTDIR/SCENE-SEED (read them all with experiments/scripts/results.py OUTDIR/*, and
on a GPU price them at lavapipe's cost with --costs: its docstring says how). `--scene NAME`
(repeatable) runs only those of the job file's scenes. Arguments after `--` go to every
batch (e.g. `-- --iterations 2`, or `-- --film 256x256` for the protocol at another
resolution). Exits non-zero if any batch did.
"""

import argparse
import subprocess
import sys
import tomllib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def scene_names(job_file):
    """The short names of the job file's scenes (`ajar` for `ajar/scene.toml`), in order."""
    jobs = tomllib.loads(Path(job_file).read_text())
    paths = list(jobs.get("scenes", [])) + [j["scene"] for j in jobs.get("jobs", []) if "scene" in j]
    names = []
    for p in paths:
        name = Path(p).parent.name or Path(p).stem
        if name not in names:
            names.append(name)
    return names


def main():
    argv = sys.argv[1:]
    extra = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1 :]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("job_file")
    ap.add_argument("out_dir")
    ap.add_argument("seeds", nargs="+", type=int)
    ap.add_argument("--scene", action="append", default=[], help="run only this scene of the job file (repeatable)")
    ap.add_argument("--parallel", type=int, default=4, help="batches at once (default 4)")
    ap.add_argument("--bin", default="target/release/vkinverse", help="the vkinverse binary")
    a = ap.parse_args(argv)
    if a.parallel < 1:
        sys.exit("batch_seeds.py: --parallel must be at least 1")
    if not Path(a.bin).is_file():
        sys.exit(f"batch_seeds.py: {a.bin}: no such binary (cargo build --release, or --bin PATH)")
    try:
        scenes = scene_names(a.job_file)
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError) as e:
        sys.exit(f"batch_seeds.py: {a.job_file}: {e}")
    if not scenes:
        sys.exit(f"batch_seeds.py: {a.job_file} names no scene")
    unknown = [s for s in a.scene if s not in scenes]
    if unknown:
        sys.exit(f"batch_seeds.py: --scene {unknown[0]}: {a.job_file} has no such scene (its scenes: {', '.join(scenes)})")
    if a.scene:
        scenes = [s for s in scenes if s in a.scene]
    Path(a.out_dir).mkdir(parents=True, exist_ok=True)

    def run(scene_seed):
        scene, seed = scene_seed
        out = Path(a.out_dir) / f"{scene}-{seed}"
        cmd = [a.bin, "batch", a.job_file, "--scene", scene, "--seed", str(seed), "-o", str(out), "--quiet", *extra]
        done = subprocess.run(cmd, capture_output=True, text=True)
        out.mkdir(parents=True, exist_ok=True)
        (out / "batch_seeds.log").write_text(done.stdout + done.stderr)
        return scene, seed, done.returncode, done.stderr.strip().splitlines()[-1:]

    failed = 0
    with ThreadPoolExecutor(a.parallel) as pool:
        for scene, seed, code, last in pool.map(run, [(s, seed) for seed in a.seeds for s in scenes]):
            print(f"{scene} seed {seed}: " + ("ok" if code == 0 else f"exit {code}: {' '.join(last)}"), flush=True)
            failed += code != 0
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
