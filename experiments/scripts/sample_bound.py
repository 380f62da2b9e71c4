#!/usr/bin/env python3
"""How soon any optimiser could reach a goal error, given the samples per pixel it renders
per iteration: a lower bound from the noise of the images a run fits.

A run fits θ to images: the target (rendered once, at the job's target_spp) and its own
renders of θ. Near the optimum the parameter error from an image's noise scales as
1/sqrt(its samples per pixel), and the two images' noises are independent, so a run whose
renders of θ hold N samples per pixel in all cannot settle below

    e(N)^2 = F^2 (1 + target_spp / N),

where F is the error from the target's noise alone. F comes from two Adam runs that differ
only in the target's samples (experiments/bound.toml): e_lo^2 - e_hi^2 = F^2 (1 - lo / hi).
Reaching a goal error E therefore needs N(E) = target_spp F^2 / (E^2 - F^2) samples per
pixel; a run that renders s samples per pixel of θ per iteration needs at least
N(E) / s iterations. Every pass that traces camera paths at θ renders it: the primal pass
(primal_spp), the adjoint pass (spp: path replay traces each of its samples once for its
radiance) and meta's finite-difference sample (fd_spp on every fd_stride-th pixel: its two
renders share their random numbers, so together they hold about one render's samples).
Meta uses the first two and carries its image with the third; Adam uses the first only.
The bound counts them all, as an optimiser could.

For each seed of the protocol runs given this prints the goal (results.py's: GOAL_MARGIN
times the best Adam-3's settled error), Adam-3's time to it, the fewest iterations and
least time meta's sample budget allows, the largest speed-up any optimiser drawing meta's
samples could have (at meta's measured time per iteration), meta's actual speed-up, and
each run's sample efficiency at the goal: N(E) over the samples of θ it had rendered when
it got there.

    python3 experiments/scripts/sample_bound.py --floor out/bound/ajar-* --scene ajar --meta LABEL \\
        [--costs OUTDIR]... OUTDIR [OUTDIR ...]

The meta runs judged are those labelled LABEL (`meta` unless given); with --costs every
run is priced as results.py prices it, so that the times are those its goals compare.
"""

import argparse
import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import GOAL_MARGIN, adam_references, costs_of, fmt, fmt_speedup, load, priced, speedup, summary, time_to_reach  # noqa: E402


def seed_of(r):
    return summary(r["dir"]).get("settings", {}).get("seed", 0)


def target_spp(r):
    return summary(r["dir"]).get("settings", {}).get("target_spp", 1024)


def floor_of(rows):
    """F, the error from the target's noise, per seed, from Adam runs that differ only in
    target_spp (the lowest and the highest)."""
    floors = {}
    by_seed = {}
    for r in rows:
        by_seed.setdefault(seed_of(r), []).append(r)
    for seed, runs in sorted(by_seed.items()):
        runs = sorted(runs, key=target_spp)
        lo, hi = runs[0], runs[-1]
        if target_spp(lo) == target_spp(hi):
            sys.exit(f"sample_bound.py: seed {seed}: the --floor runs need two target_spp values")
        f2 = (lo["settled"] ** 2 - hi["settled"] ** 2) / (1.0 - target_spp(lo) / target_spp(hi))
        if f2 <= 0:
            sys.exit(f"sample_bound.py: seed {seed}: the run with the better target settles higher; no floor")
        floors[seed] = (math.sqrt(f2), target_spp(lo), lo["settled"], hi["settled"])
    return floors


def samples_per_iteration(r):
    """Samples per pixel of θ that one iteration renders (the module docs)."""
    s = r["primal_spp"] + r["spp"]
    if r["optimiser"].startswith("meta"):
        s += r["fd_spp"] / r["fd_stride"]
    return s


def iteration_at(points, time):
    """The iteration logged at `time` on the curve (None for None)."""
    if time is None:
        return None
    return next((i for i, t, _ in points if t >= time), points[-1][0])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--floor", nargs="+", required=True, help="batch outputs of experiments/bound.toml")
    ap.add_argument("--scene", required=True, help="the scene's short name (ajar)")
    ap.add_argument("--meta", default="meta", help="the label of the meta runs to judge (default: meta)")
    ap.add_argument("--costs", action="append", default=[], help="price the runs at these runs' seconds per iteration (results.py's --costs)")
    ap.add_argument("protocol", nargs="+", help="batch outputs of the protocol (results.py's inputs)")
    a = ap.parse_args()
    floors = floor_of(load(a.floor).get(a.scene, []))
    if not floors:
        sys.exit(f"sample_bound.py: no {a.scene} runs in --floor")
    by_scene = load(a.protocol)
    if a.costs:
        by_scene = priced(by_scene, costs_of(load(a.costs)))
    rows = by_scene.get(a.scene, [])
    by_seed = {}
    for r in rows:
        by_seed.setdefault(seed_of(r), []).append(r)
    print(f"{a.scene}: the target's noise floor F per seed (Adam's settled error at the lowest and highest target_spp):")
    for seed, (f, spp, lo, hi) in floors.items():
        print(f"  seed {seed}: F = {f:.4f} (settled {lo:.4f} at {spp} spp, {hi:.4f} at the higher)")
    f_all = statistics.median(v[0] for v in floors.values())
    print(f"  median F = {f_all:.4f}\n")
    print("| seed | goal E | Adam-3 lr | Adam-3 to E: iterations, s | N(E) spp | meta's renders, spp / it | meta's fewest iterations, least s | largest speed-up | meta's speed-up | sample efficiency at E: Adam-3, meta |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    beaten = []
    for seed, runs in sorted(by_seed.items()):
        _, best, _ = adam_references(runs)
        metas = [r for r in runs if r["optimiser"] == a.meta]
        if best is None or not metas:
            continue
        meta = metas[0]
        f, spp_t, _, _ = floors.get(seed, (f_all, target_spp(best), None, None))
        goal = GOAL_MARGIN * best["settled"]
        # None where the goal lies at or below the target's floor: no number of samples.
        need = spp_t * f * f / (goal * goal - f * f) if goal > f else None
        t_adam = time_to_reach(best["smooth"], goal)
        t_meta = time_to_reach(meta["smooth"], goal)
        it_adam = iteration_at(best["smooth"], t_adam)
        it_meta = iteration_at(meta["smooth"], t_meta)
        s_meta = samples_per_iteration(meta)
        sec_meta = meta["time_s"] / meta["iterations"]
        fewest = math.ceil(need / s_meta) if need is not None else None
        least = fewest * sec_meta if fewest is not None else None
        largest = t_adam / least if t_adam is not None and least else None
        def eff(it, r):
            if not it or need is None:
                return "-"
            e = need / (it * samples_per_iteration(r))
            if e > 1.0:
                beaten.append(f"{seed} ({r['optimiser']})")
            return f"{e:.0%}"

        print(f"| {seed} | {goal:.4f} | {best['rate']} | {fmt(it_adam, 'd')}, {fmt(t_adam, '.2f')} | {fmt(need, '.0f')} | {s_meta:g} | "
              f"{fmt(fewest, 'd')}, {fmt(least, '.2f')} | {fmt(largest, '.2f')}× | {fmt_speedup(speedup(t_adam, t_meta, best['time_s']))} | "
              f"{eff(it_adam, best)}, {eff(it_meta, meta)} |")
    if beaten:
        print(f"\nRuns that beat the bound, at seeds {', '.join(beaten)}: its premise, an error from the images' "
              "noise alone, does not hold on this scene (part of its error moves with no image, such as parameters "
              "the images barely constrain), and the bound says nothing there.")


if __name__ == "__main__":
    main()
