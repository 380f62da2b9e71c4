#!/usr/bin/env python3
"""Tables of docs/results.md from the output directory of `vkinverse batch` (standard
library only):

    python3 scripts/results.py OUTDIR > tables.md

Per scene, one row per finished job: samples per pixel, iterations, milliseconds per
iteration, the final parameter error, the settled error (mean over the last fifth of the
iterations, where noisy runs wander around their optimum), the error at equal time (at the
wall time of the meta-estimator's whole run, or the job's last point if it ran shorter),
and the time each job needs to reach the final error of Adam at the largest spp, with
that job's own time divided by it (the speed-up).
"""

import csv
import json
import sys
from pathlib import Path


def curve(job_dir):
    """(time_s, param_error) points of a job's log.csv, row 0 included."""
    points = []
    with open(job_dir / "log.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["param_error"]:
                points.append((float(row["time_s"]), float(row["param_error"])))
    return points


def time_to_reach(points, level):
    for t, e in points:
        if e <= level:
            return t
    return None


def error_at(points, time):
    """The last logged error at or before `time`."""
    best = points[0][1]
    for t, e in points:
        if t > time:
            break
        best = e
    return best


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: results.py OUTDIR")
    out = Path(sys.argv[1])
    results = json.loads((out / "results.json").read_text())["results"]
    by_scene = {}
    for r in results:
        if r["status"] != "ok":
            print(f"<!-- job {r['job']} {r['label']} failed: {r['message']} -->")
            continue
        scene = Path(r["scene"]).parent.name
        by_scene.setdefault(scene, []).append(r)

    for scene, rows in by_scene.items():
        curves = {r["label"]: curve(out / r["dir"]) for r in rows}
        meta = next((r for r in rows if r["optimiser"] == "meta"), None)
        adams = [r for r in rows if r["optimiser"] == "adam"]
        largest = max(adams, key=lambda r: r["spp"]) if adams else None
        goal = curves[largest["label"]][-1][1] if largest else None
        goal_time = time_to_reach(curves[largest["label"]], goal) if largest else None
        equal_time = meta["time_s"] if meta else None
        initial = next(iter(curves.values()))[0][1]

        print(f"### {scene}\n")
        print(f"Initial parameter error {initial:.4f}.", end=" ")
        if largest:
            print(f"Goal: Adam at {largest['spp']} spp's final error, {goal:.4f}, reached at {goal_time:.1f} s.", end="")
        print("\n")
        print("| run | spp | iterations | ms / iteration | final error | settled error | error at %s s | time to goal (s) | speed-up |"
              % (f"{equal_time:.0f}" if equal_time else "equal time"))
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            pts = curves[r["label"]]
            errors = [e for _, e in pts[1:]]
            tail = errors[len(errors) - max(1, len(errors) // 5):]
            settled = sum(tail) / len(tail)
            spp = f"{r['spp']}+1 FD" if r["optimiser"] == "meta" else str(r["spp"])
            at = error_at(pts, equal_time) if equal_time else None
            reach = time_to_reach(pts, goal) if goal is not None else None
            speedup = goal_time / reach if reach and goal_time else None
            print(
                f"| {r['label']} | {spp} | {r['iterations']} | {1000 * r['time_s'] / r['iterations']:.0f} | {errors[-1]:.4f} | {settled:.4f} | "
                + (f"{at:.4f}" if at is not None else "-")
                + " | " + (f"{reach:.1f}" if reach is not None else "not reached")
                + " | " + (f"{speedup:.1f}×" if speedup else "-") + " |"
            )
        print()


if __name__ == "__main__":
    main()
