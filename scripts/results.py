#!/usr/bin/env python3
"""Tables of docs/results.md from the output directory of `vkinverse batch` (standard
library only):

    python3 scripts/results.py OUTDIR [OUTDIR ...] > tables.md

(several output directories, e.g. the shards of one batch, are read as one).

Per scene, one row per finished job: samples per pixel, iterations, milliseconds per
iteration, the parameter error at equal iterations (the shortest run's count, as in the
equal-iteration plots of Bálint et al. 2023), the final error, the settled error (mean over
the last fifth of the iterations, where noisy runs wander around their optimum), the error
at equal time (at the wall time of the first meta-estimator run, or the job's last point if
it ran shorter), and the time from which each job stays at or below the goal, 1.1 × the
settled error of Adam at the largest spp (a run hovers around its own settled error, hence
the margin), with the goal run's own time divided by it (the speed-up). For meta-estimator
runs, the last column is the effective number of gradient samples it averaged at the end,
n_eff = 1/(1 - alpha), per parameter (summary.json's meta_n_eff).

Noisy runs cross a level by chance long before they stay below it, so errors at a given
iteration or time and the times to reach the goal are read off each curve smoothed by a
trailing mean over a twentieth of its iterations.
"""

import csv
import json
import sys
from pathlib import Path

# The goal is this multiple of the settled error of Adam at the largest spp.
GOAL_MARGIN = 1.1


def curve(job_dir):
    """(time_s, param_error) points of a job's log.csv, row 0 (the start) first."""
    points = []
    with open(job_dir / "log.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["param_error"]:
                points.append((float(row["time_s"]), float(row["param_error"])))
    return points


def smoothed(points):
    """The curve with each error after the start replaced by the trailing mean over a
    twentieth of the run's iterations (at least one)."""
    window = max(1, (len(points) - 1) // 20)
    out = [points[0]]
    for i in range(1, len(points)):
        lo = max(1, i - window + 1)
        errors = [e for _, e in points[lo : i + 1]]
        out.append((points[i][0], sum(errors) / len(errors)))
    return out


def time_to_reach(points, level):
    """The first time from which the curve stays at or below `level` to its end."""
    reached = None
    for t, e in points:
        if e > level:
            reached = None
        elif reached is None:
            reached = t
    return reached


def settled(points):
    """Mean error over the last fifth of the iterations."""
    errors = [e for _, e in points[1:]]
    tail = errors[len(errors) - max(1, len(errors) // 5) :]
    return sum(tail) / len(tail)


def error_at(points, time):
    """The last logged error at or before `time`."""
    best = points[0][1]
    for t, e in points:
        if t > time:
            break
        best = e
    return best


def n_eff(job_dir):
    """The meta-estimator's final n_eff per parameter, as "name n, ..." (short names)."""
    try:
        values = json.loads((job_dir / "summary.json").read_text()).get("meta_n_eff") or {}
    except (OSError, json.JSONDecodeError):
        return "-"
    return ", ".join(f"{name.split('.')[-1]} {v:.1f}" for name, v in values.items()) or "-"


def main():
    if len(sys.argv) < 2:
        sys.exit("usage: results.py OUTDIR [OUTDIR ...]")
    results = []
    for arg in sys.argv[1:]:
        for r in json.loads((Path(arg) / "results.json").read_text())["results"]:
            results.append(dict(r, dir=Path(arg) / r["dir"]))
    by_scene = {}
    for r in results:
        if r["status"] != "ok":
            print(f"<!-- job {r['job']} {r['label']} failed: {r['message']} -->")
            continue
        scene = Path(r["scene"]).parent.name
        by_scene.setdefault(scene, []).append(r)

    for scene, rows in by_scene.items():
        raw = {r["label"]: curve(r["dir"]) for r in rows}
        curves = {label: smoothed(points) for label, points in raw.items()}
        meta = next((r for r in rows if r["optimiser"] == "meta"), None)
        adams = [r for r in rows if r["optimiser"] == "adam"]
        largest = max(adams, key=lambda r: r["spp"]) if adams else None
        goal = GOAL_MARGIN * settled(raw[largest["label"]]) if largest else None
        goal_time = time_to_reach(curves[largest["label"]], goal) if largest else None
        equal_time = meta["time_s"] if meta else None
        equal_iterations = min(len(p) - 1 for p in raw.values())
        initial = next(iter(raw.values()))[0][1]

        print(f"### {scene}\n")
        print(f"Initial parameter error {initial:.4f}.", end=" ")
        if largest:
            reached = f"reached at {goal_time:.1f} s" if goal_time is not None else "not reached by its smoothed curve"
            print(f"Goal: {GOAL_MARGIN} × the settled error of Adam at {largest['spp']} spp, {goal:.4f}, {reached}.", end="")
        print("\n")
        print("| run | spp | iterations | ms / iteration | error at iteration %d | final error | settled error | error at %s s | time to goal (s) | speed-up | meta n_eff |"
              % (equal_iterations, f"{equal_time:.0f}" if equal_time else "equal time"))
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            pts = curves[r["label"]]
            spp = f"{r['spp']}+1 FD" if r["optimiser"] == "meta" else str(r["spp"])
            at = error_at(pts, equal_time) if equal_time else None
            reach = time_to_reach(pts, goal) if goal is not None else None
            speedup = goal_time / reach if reach and goal_time else None
            print(
                f"| {r['label']} | {spp} | {r['iterations']} | {1000 * r['time_s'] / r['iterations']:.0f} | {pts[equal_iterations][1]:.4f} "
                + f"| {raw[r['label']][-1][1]:.4f} | {settled(raw[r['label']]):.4f} | "
                + (f"{at:.4f}" if at is not None else "-")
                + " | " + (f"{reach:.1f}" if reach is not None else "not reached")
                + " | " + (f"{speedup:.1f}×" if speedup else "-")
                + " | " + (n_eff(r["dir"]) if r["optimiser"] == "meta" else "-") + " |"
            )
        print()


if __name__ == "__main__":
    main()
