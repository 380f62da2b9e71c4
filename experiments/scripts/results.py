#!/usr/bin/env python3
"""Tables of docs/results.md from the output directories of `vkinverse batch` (standard
library only):

    python3 experiments/scripts/results.py OUTDIR [OUTDIR ...] > tables.md          # the protocol
    python3 experiments/scripts/results.py --pilot OUTDIR [OUTDIR ...] > pilot.md   # candidate configurations
    python3 experiments/scripts/results.py --depth OUTDIR [OUTDIR ...] > depth.md   # meta's averaging depth
    python3 experiments/scripts/results.py --goals OUTDIR [OUTDIR ...] > goals.md   # the goal over scenes and seeds
    python3 experiments/scripts/results.py --seeds OUTDIR [OUTDIR ...] > seeds.md   # the same, one row per seed

Any mode takes `--costs OUTDIR` (repeatable) before the output directories: each run's times
are then its iterations at the median cost per iteration of the runs of the same scene,
kind (meta or Adam, and the same samples per pixel) and film in those directories, e.g. runs
on a GPU, whose clock moves with its load, priced at what lavapipe's runs of the protocol
cost (at 256 x 256: `vkinverse batch JOBS --film 256x256 --iterations 10` on lavapipe).

Several output directories (e.g. the shards of one batch) are read as one.

The protocol (experiments/protocol.toml) runs per scene: Adam at 3 spp at each rate of a grid,
Adam at 32 and 64 spp, and the meta-estimator (spec `meta`, its defaults) at 2 + 1
finite-difference spp with the scene's own settings. Per scene this prints
- one row per run: spp, rate, iterations, ms per iteration, the settled error (the mean
  over the last fifth of the run, where a noisy run wanders around its optimum), the error at
  equal iterations and at equal time, and the times at which the run reaches two goals: the
  settled error of the best-rate Adam at 3 spp ("Adam-3"), and that of Adam at 64 spp
  ("Adam-64"), each with a margin of GOAL_MARGIN;
- a verdict line: whether meta settles at or below Adam-3, its speed-up to Adam-3's goal
  (Adam-3's own time to it over meta's), and its speed-up to Adam-64's.

Noisy runs cross a level by chance long before they stay below it, so errors at a given
iteration or time, and the times to a goal, are read off each curve smoothed by a trailing
mean over a twentieth of its iterations; the time to a goal is the first time from which
the smoothed curve stays at or below it to the run's end.

The pilot table has one row per meta configuration and one column per scene: its settled
error (the geometric mean over its runs, e.g. seeds) relative to the best Adam run on that
scene, and their geometric mean over scenes. Where two configurations ran one scene at the
same seeds (at least two), a second table compares each with the first configuration seed
by seed, at equal iterations (settled errors) and at equal time (smoothed errors at the
shorter run's end), each seed's run taken from the first directory that has one.

The goals table has one row per meta configuration: at how many of the scene-seeds it ran
it meets issue 14's goal against the best Adam-3 and the Adam-64 of the same scene and seed
(settled at or below that Adam-3, and at least 3x as fast to its error), and at how many
seeds it reaches Adam-64's error at least 10x sooner than Adam-64 on at least two scenes.
The seeds table gives the figures behind it, one row per scene, seed and configuration.

The depth table has one row per meta run: at a few iterations, how many gradient samples
its estimate averages (n_eff, the mean over all its parameters, from optimiser.csv), the
share of parameters whose averaging grew by the most one iteration allows (the clip
alpha <= 1/(2 - alpha_prev): n_eff at most one more than before, so n_eff <= t), and the
RMS of the estimate over its standard deviation (the worst-resolved group's). Adam's first
moment averages (1 + beta1)/(1 - beta1) = 19 samples' worth at beta1 = 0.9, which is the
depth meta's estimate has to exceed to be the less noisy of the two.
"""

import csv
import json
import math
import statistics
import sys
import tomllib
from pathlib import Path

# A goal is this multiple of a run's settled error: a run hovers around its own settled
# error, so the run itself only stays below a level a little above it.
GOAL_MARGIN = 1.1


def curve(job_dir):
    """(iteration, time_s, param_error) of a job's log.csv, row 0 (the start) first."""
    points = []
    with open(job_dir / "log.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["param_error"]:
                points.append((int(row["iteration"]), float(row["time_s"]), float(row["param_error"])))
    return points


def smoothed(points):
    """The curve with each error after the start replaced by the trailing mean over a
    twentieth of the run's iterations (at least one)."""
    window = max(1, (len(points) - 1) // 20)
    out = [points[0]]
    for i in range(1, len(points)):
        lo = max(1, i - window + 1)
        errors = [p[2] for p in points[lo : i + 1]]
        out.append((points[i][0], points[i][1], sum(errors) / len(errors)))
    return out


def time_to_reach(points, level):
    """The first time from which the curve stays at or below `level` to its end."""
    reached = None
    for _, t, e in points:
        if e > level:
            reached = None
        elif reached is None:
            reached = t
    return reached


def settled(points):
    """Mean error over the last fifth of the iterations."""
    errors = [p[2] for p in points[1:]]
    tail = errors[len(errors) - max(1, len(errors) // 5) :]
    return sum(tail) / len(tail)


def error_at_time(points, time):
    """The last error logged at or before `time`."""
    best = points[0][2]
    for _, t, e in points:
        if t > time:
            break
        best = e
    return best


def error_at_iteration(points, iteration):
    """The error at `iteration`, or None if the run is shorter."""
    return next((e for i, _, e in points if i == iteration), None)


def summary(job_dir):
    try:
        return json.loads((job_dir / "summary.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def image_excess(job_dir):
    """The result's image error less the reference's (summary.json; both from the same
    random numbers): how much further the expected image is from the target than the
    reference's, free of the renders' noise. None for runs from before it was measured."""
    sm = summary(job_dir)
    final, ref = sm.get("final_image_error"), sm.get("reference_image_error")
    return None if final is None or ref is None else final - ref


def rate(job_dir):
    """The run's learning rate as given: a number, or "scene" for the scene's own rates."""
    st = summary(job_dir).get("settings", {})
    return f"{st['lr']:g}" if st.get("lr_replaces_param_rates") else "scene"


def film_of(job_dir, scene):
    """The film a run rendered, (width, height): from its summary.json, or for runs from
    before summaries recorded it (which could not change the film of a TOML scene in a
    batch), from the scene file's [film]; None where neither says."""
    film = summary(job_dir).get("film")
    if film:
        return tuple(film)
    try:
        f = tomllib.loads(Path(scene).read_text()).get("film", {})
        return (f["width"], f["height"])
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, UnicodeDecodeError):
        return None


def load(args):
    results = []
    for arg in args:
        for r in json.loads((Path(arg) / "results.json").read_text())["results"]:
            results.append(dict(r, dir=Path(arg) / r["dir"]))
    by_scene = {}
    for r in results:
        if r["status"] != "ok":
            print(f"<!-- job {r['job']} {r['label']} {r['status']}: {r['message']} -->")
            continue
        r["raw"] = curve(r["dir"])
        r["smooth"] = smoothed(r["raw"])
        r["settled"] = settled(r["raw"])
        r["rate"] = rate(r["dir"])
        settings = summary(r["dir"]).get("settings", {})
        r["fd_stride"] = settings.get("fd_stride", 1)
        r["fd_spp"] = settings.get("fd_spp", 1)
        r["primal_spp"] = settings.get("primal_spp", 4)
        r["film"] = film_of(r["dir"], r["scene"])
        by_scene.setdefault(Path(r["scene"]).parent.name, []).append(r)
    return by_scene


def geometric_mean(xs):
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def fmt(v, spec=".4f"):
    return "-" if v is None else format(v, spec)


def fmt_short(v):
    """A time or duration to a tenth above 1 and to two significant digits below, so that
    a GPU's fractions of a millisecond show as well as lavapipe's tens of milliseconds."""
    if v is None:
        return "-"
    return f"{v:.0f}" if v >= 100 else f"{v:.1f}" if v >= 1 else f"{v:.2g}"


class Bound(float):
    """A speed-up known only from below: the reference run never stayed at the goal, so
    its time to it is at least its whole run's."""


class AtStart(float):
    """A speed-up of 0 because the reference was at its goal from its start (a run that
    hardly moves: its settled error is its initial one), not because this run never
    got there."""


def speedup(reference_time, time, reference_end=None):
    """The reference's time to a goal over this run's; 0.0 if this run never gets there,
    None if neither does. Where only this run gets there, the reference's whole run time
    (`reference_end`) over this run's time, as a lower bound."""
    if reference_time is None:
        if time is None or reference_end is None:
            return None
        return Bound(reference_end / time) if time > 0 else math.inf
    if time is None:
        return 0.0
    if time > 0 and reference_time == 0:
        return AtStart(0.0)
    return reference_time / time if time > 0 else math.inf


def fmt_speedup(s):
    if s is None:
        return "-"
    if isinstance(s, AtStart):
        return "0× (the reference at its goal from the start)"
    if s == 0.0:
        return "never"
    if s == math.inf:
        return "∞"
    return f"> {s:.1f}×" if isinstance(s, Bound) else f"{s:.1f}×"


def short_names(groups):
    """The shortest endings of the parameter groups' names that still tell them apart
    (`materials.left.base_color` -> `left.base_color` beside `materials.right.base_color`)."""
    groups = list(groups)
    most = max((g.count(".") + 1 for g in groups), default=1)
    for k in range(1, most + 1):
        ends = {g: ".".join(g.split(".")[-k:]) for g in groups}
        if len(set(ends.values())) == len(groups):
            return ends
    return {g: g for g in groups}


def adam_references(rows):
    """The Adam-3 grid (by rate), its best run (the lowest settled error) and the Adam run of
    the most samples per pixel (Adam-64) among `rows`."""
    grid = sorted((r for r in rows if r["optimiser"] == "adam" and r["spp"] == 3), key=lambda r: float(r["rate"]) if r["rate"] != "scene" else 0.0)
    best = min(grid, key=lambda r: r["settled"]) if grid else None
    adam64 = max((r for r in rows if r["optimiser"] == "adam" and r["spp"] > 3), key=lambda r: r["spp"], default=None)
    return grid, best, adam64


def grid_edge(grid, best):
    """"lowest" or "highest" where the best Adam-3 ran at that end of a grid of at least
    three rates (the grid may then not hold Adam's best rate), else None."""
    rates = [r["rate"] for r in grid if r["rate"] != "scene"]
    if best is None or len(rates) < 3 or best["rate"] not in (rates[0], rates[-1]):
        return None
    return "lowest" if best["rate"] == rates[0] else "highest"


def verdict(meta, best, adam64):
    """A meta run against the best Adam-3 and Adam-64 of its scene: its settled error over
    Adam-3's, its speed-ups to their goals, and whether it meets the goal (at or below
    Adam-3, at least 3x as fast to Adam-3's goal)."""
    goal3 = GOAL_MARGIN * best["settled"]
    s3 = speedup(time_to_reach(best["smooth"], goal3), time_to_reach(meta["smooth"], goal3), best["time_s"])
    s64 = None
    if adam64:
        goal64 = GOAL_MARGIN * adam64["settled"]
        s64 = speedup(time_to_reach(adam64["smooth"], goal64), time_to_reach(meta["smooth"], goal64), adam64["time_s"])
    return dict(meta=meta["settled"], adam3=best["settled"], rate=best["rate"], ratio=meta["settled"] / best["settled"], s3=s3, s64=s64,
                adam64=adam64["settled"] if adam64 else None, ok=meta["settled"] <= best["settled"] and s3 is not None and s3 >= 3.0)


def protocol(by_scene):
    verdicts = []
    for scene, rows in by_scene.items():
        metas = [r for r in rows if r["optimiser"].startswith("meta")]
        # The default: spec `meta` at the scene's own settings (other meta rows are shown too).
        meta = next((r for r in metas if r["optimiser"] == "meta" and r["rate"] == "scene"), metas[0] if metas else None)
        grid, best, adam64 = adam_references(rows)
        edge = grid_edge(grid, best)
        goal3 = GOAL_MARGIN * best["settled"] if best else None
        goal64 = GOAL_MARGIN * adam64["settled"] if adam64 else None
        equal_time = meta["time_s"] if meta else None
        equal_it = min(meta["iterations"], adam64["iterations"]) if meta and adam64 else None
        initial = rows[0]["raw"][0][2]

        print(f"### {scene}\n")
        print(
            f"Initial parameter error {initial:.4f}. Adam-3: the best rate of the grid "
            + (", ".join(f"{r['rate']}" for r in grid) or "-")
            + (f" is {best['rate']}, settled error {best['settled']:.4f}" if best else "")
            + (f" (the grid's {edge} rate: a wider grid may hold a better one)" if edge else "")
            + (f"; Adam-{adam64['spp']} settles at {adam64['settled']:.4f} after {adam64['iterations']} iterations" if adam64 else "")
            + ".\n"
        )
        print(
            f"| run | spp | lr | iterations | ms / iteration | settled error | error at iteration {fmt(equal_it, 'd')} "
            + f"| error at {fmt_short(equal_time)} s | time to Adam-3 goal (s) | time to Adam-64 goal (s) | image error over the reference's | meta n_eff |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            sm = r["smooth"]
            spp = f"{r['spp']}+1 FD" if r["optimiser"].startswith("meta") else str(r["spp"])
            mark = " (best)" if r is best else " (default)" if r is meta else ""
            n_eff = summary(r["dir"]).get("meta_n_eff") or {}
            n_eff = ", ".join(f"{short[k]} {v:.1f}" for short in [short_names(n_eff)] for k, v in n_eff.items()) or "-"
            print(
                f"| {r['optimiser']}{mark} | {spp} | {r['rate']} | {r['iterations']} | {fmt_short(1000 * r['time_s'] / r['iterations'])} "
                + f"| {r['settled']:.4f} | {fmt(error_at_iteration(sm, equal_it) if equal_it else None)} "
                + f"| {fmt(error_at_time(sm, equal_time) if equal_time else None)} "
                + f"| {fmt_short(time_to_reach(sm, goal3) if goal3 else None)} | {fmt_short(time_to_reach(sm, goal64) if goal64 else None)} "
                + f"| {fmt(image_excess(r['dir']), '.2e')} | {n_eff} |"
            )
        print()
        if meta and best:
            v = dict(verdict(meta, best, adam64), scene=scene, im_meta=image_excess(meta["dir"]), im_adam=image_excess(best["dir"]))
            verdicts.append(v)
            ratio, at_or_below, s3, s64 = v["ratio"], v["meta"] <= v["adam3"], v["s3"], v["s64"]
            print(
                f"Meta settles at {ratio:.2f}× Adam-3's error ({'at or below' if at_or_below else 'above'}); "
                + f"to Adam-3's goal it is {fmt_speedup(s3)} as fast as Adam-3, to Adam-64's goal {fmt_speedup(s64)} as fast as Adam-64.\n"
            )
    if verdicts:
        print("### Summary\n")
        print("| scene | Adam-3 best lr | Adam-3 settled | Adam-64 settled | meta settled | meta / Adam-3 | speed-up to Adam-3's goal | speed-up to Adam-64's goal | goal (≤ Adam-3, ≥ 3×) | image error over the reference's: meta, Adam-3 |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for v in verdicts:
            print(
                f"| {v['scene']} | {v['rate']} | {v['adam3']:.4f} | {fmt(v['adam64'])} | {v['meta']:.4f} | {v['ratio']:.2f} "
                + f"| {fmt_speedup(v['s3'])} | {fmt_speedup(v['s64'])} | {'met' if v['ok'] else 'not met'} | {fmt(v['im_meta'], '.1e')}, {fmt(v['im_adam'], '.1e')} |"
            )
        print()


# A configuration is a meta spec with the rate it ran at (when not the scene's own), its
# finite-difference pixel stride and spp (when not 1) and its primal render's spp (when
# not 4).
def config(r):
    lr = "" if r["rate"] == "scene" else f" (lr {r['rate']})"
    stride = "" if r["fd_stride"] == 1 else f" (fd_stride {r['fd_stride']})"
    fd = "" if r["fd_spp"] == 1 else f" (fd_spp {r['fd_spp']})"
    primal = "" if r["primal_spp"] == 4 else f" (primal_spp {r['primal_spp']})"
    return r["optimiser"] + lr + stride + fd + primal


def pilot(by_scene):
    scenes = list(by_scene)

    configs = []
    for rows in by_scene.values():
        for r in rows:
            if r["optimiser"].startswith("meta") and config(r) not in configs:
                configs.append(config(r))
    best = {s: adam_references(rows)[1] for s, rows in by_scene.items()}
    print("Settled error relative to the best Adam run of the pilot on the scene (below 1: meta better):\n")
    print("| configuration | " + " | ".join(scenes) + " | geometric mean |")
    print("|---|" + "---|" * (len(scenes) + 1))
    print("| best Adam (3 spp): settled error, lr | " + " | ".join(f"{best[s]['settled']:.4f}, {best[s]['rate']}" if best[s] else "-" for s in scenes) + " | |")
    for c in configs:
        ratios = []
        for s in scenes:
            # Several runs of one configuration (seeds): the geometric mean of their settled errors.
            runs = [r["settled"] for r in by_scene[s] if r["optimiser"].startswith("meta") and config(r) == c]
            settled = geometric_mean(runs) if runs else None
            ratios.append(settled / best[s]["settled"] if settled and best[s] else None)
        known = [x for x in ratios if x]
        gm = geometric_mean(known) if known else None
        print(f"| {c} | " + " | ".join(fmt(x, ".2f") for x in ratios) + f" | {fmt(gm, '.2f')} |")
    print()
    paired(by_scene, configs, config)


def paired(by_scene, configs, config):
    """Each configuration against the first, seed by seed, where both ran a scene at the
    same seed: the geometric mean over seeds of the ratio of settled errors (equal
    iterations) and of the smoothed errors at the shorter run's end (equal time), and at how
    many seeds each ratio is below 1."""
    rows = []
    for c in configs[1:]:
        for s, runs in by_scene.items():
            first, other = {}, {}
            for r in runs:
                if r["optimiser"].startswith("meta"):
                    # A seed run in several directories: the first directory's run.
                    if config(r) == configs[0]:
                        first.setdefault(r["seed"], r)
                    elif config(r) == c:
                        other.setdefault(r["seed"], r)
            seeds = sorted(set(first) & set(other))
            if len(seeds) < 2:
                continue
            it, tm = [], []
            for seed in seeds:
                a, b = first[seed], other[seed]
                it.append(a["settled"] / b["settled"])
                end = min(a["raw"][-1][1], b["raw"][-1][1])
                tm.append(error_at_time(a["smooth"], end) / error_at_time(b["smooth"], end))
            rows.append((c, s, len(seeds), geometric_mean(it), sum(x < 1 for x in it), geometric_mean(tm), sum(x < 1 for x in tm)))
    if not rows:
        return
    print(f"{configs[0]} against each configuration at the same seeds (below 1: {configs[0]} better):\n")
    print("| configuration | scene | seeds | settled error, ratio (geometric mean) | lower at | error at equal time, ratio | lower at |")
    print("|---|---|---|---|---|---|---|")
    for c, s, n, it, wi, tm, wt in rows:
        print(f"| {c} | {s} | {n} | {it:.2f} | {wi} | {tm:.2f} | {wt} |")
    print()


DEPTH_ITERATIONS = (25, 50, 100, 300, 1000)


def depth(by_scene):
    print("Meta's averaging depth: n_eff (mean over the parameters), the share clipped (growing by one"
          " per iteration), and the estimate's RMS over its standard deviation (the lowest of its groups):\n")
    print("| scene | run | seed | " + " | ".join(f"iteration {i}" for i in DEPTH_ITERATIONS) + " |")
    print("|---|---|---|" + "---|" * len(DEPTH_ITERATIONS))
    for s, rows in by_scene.items():
        for r in rows:
            if not r["optimiser"].startswith("meta"):
                continue
            by_it = {}
            with open(r["dir"] / "optimiser.csv", newline="") as f:
                for row in csv.DictReader(f):
                    by_it.setdefault(int(row["iteration"]), []).append(row)
            cells = []
            for i in DEPTH_ITERATIONS:
                groups = by_it.get(i)
                if not groups:
                    cells.append("-")
                    continue
                n = sum(float(g["elements"]) for g in groups)
                n_eff = sum(float(g["n_eff_mean"]) * float(g["elements"]) for g in groups) / n
                clipped = sum(float(g["clipped"]) * float(g["elements"]) for g in groups) / n
                snr = min(float(g["rms_mean"]) / float(g["sd_mean"]) if float(g["sd_mean"]) > 0 else math.inf for g in groups)
                cells.append(f"{n_eff:.0f}, {clipped:.2f}, {snr:.1f}")
            print(f"| {s} | {config(r)} | {r.get('seed', '-')} | " + " | ".join(cells) + " |")
    print()


def cost_class(r):
    """What one iteration of a run traces: its kind, sample counts and film. The meta
    variants of a step rule trace alike, so they share a class."""
    kind = "meta" if r["optimiser"].startswith("meta") else "adam"
    return (kind, r["spp"], r["primal_spp"], r["fd_spp"], r["fd_stride"], "carry_adjoint=off" in r["optimiser"], r["film"])


def costs_of(by_scene):
    """The median seconds per iteration of each scene's runs of each cost class."""
    seconds = {}
    for s, rows in by_scene.items():
        for r in rows:
            seconds.setdefault((s, cost_class(r)), []).append(r["time_s"] / r["iterations"])
    return {k: statistics.median(v) for k, v in seconds.items()}


def priced(by_scene, costs):
    """Each run's times replaced by its iterations at the cost `costs` gives its scene and
    cost class (from runs on another device: a GPU's runs priced at lavapipe's cost, so
    that its clock, which moves with its load, does not decide who reaches a goal first)."""
    for s, rows in by_scene.items():
        for r in rows:
            cost = costs.get((s, cost_class(r)))
            if cost is None:
                film = "x".join(map(str, r["film"])) if r["film"] else "an unknown film"
                sys.exit(f"results.py: no run of {s} like {config(r)} (spp {r['spp']}, {film}) in the --costs directories to price it by")
            r["raw"] = [(i, i * cost, e) for i, _, e in r["raw"]]
            r["smooth"] = smoothed(r["raw"])
            r["time_s"] = r["iterations"] * cost
    return by_scene


def verdicts(by_scene):
    """Every meta run's verdict against the best Adam-3 and the Adam-64 of its own scene and
    seed, by configuration and (scene, seed) (a seed run in several directories: the first
    directory's run), and the scenes' seeds whose best Adam-3 ran at an end of its grid."""
    runs = {}
    edges = {}
    for s, rows in by_scene.items():
        for seed in sorted({r["seed"] for r in rows}):
            at = [r for r in rows if r["seed"] == seed]
            grid, best, adam64 = adam_references(at)
            if best is None:
                continue
            edge = grid_edge(grid, best)
            if edge:
                edges.setdefault(s, []).append(f"{seed} ({edge})")
            for r in at:
                if r["optimiser"].startswith("meta"):
                    runs.setdefault(config(r), {}).setdefault((s, seed), verdict(r, best, adam64))
    return runs, edges


def seeds(by_scene):
    """Per scene and seed, every meta configuration's verdict: the figures that `--goals`
    counts, one row each, so that a gain or loss at one seed can be read off."""
    runs, _ = verdicts(by_scene)
    print("Per scene and seed: settled error over the best Adam-3's (its rate), speed-up to Adam-3's goal,"
          " speed-up to Adam-64's goal, and whether the goal is met:\n")
    print("| scene | seed | configuration | settled / Adam-3 | Adam-3 rate | to Adam-3's goal | to Adam-64's goal | goal |")
    print("|---|---|---|---|---|---|---|---|")
    for s in by_scene:
        for seed in sorted({sd for vs in runs.values() for sc, sd in vs if sc == s}):
            for c, vs in runs.items():
                v = vs.get((s, seed))
                if v is not None:
                    print(f"| {s} | {seed} | {c} | {v['ratio']:.2f} | {v['rate']} | {fmt_speedup(v['s3'])} | {fmt_speedup(v['s64'])} | {'met' if v['ok'] else 'not met'} |")
    print()


def goals(by_scene):
    """Per meta configuration, over every scene and seed: how often it meets the goal of
    issue 14 against the best Adam-3 and Adam-64 of the same scene and seed."""
    runs, edges = verdicts(by_scene)
    scenes = list(by_scene)
    # Per configuration, its verdicts scene by scene.
    per_scene = {c: {s: [v for (sc, _), v in vs.items() if sc == s] for s in scenes} for c, vs in runs.items()}
    print("Goals per configuration: at or below the best Adam-3 of the same seed and at least 3× as fast to"
          " its error (scene by scene: seeds met of seeds run), and Adam-64's error at least 10× sooner than Adam-64:\n")
    print("| configuration | goal met | " + " | ".join(scenes) + " | settled / Adam-3 (geometric mean) | settled at or below Adam-3 | seeds with 10× Adam-64 on two scenes |")
    print("|---|---|" + "---|" * len(scenes) + "---|---|---|")
    for c, vs in runs.items():
        met = [f"{sum(v['ok'] for v in mine)}/{len(mine)}" if mine else "-" for mine in per_scene[c].values()]
        seeds = sorted({seed for _, seed in vs})
        ten = [seed for seed in seeds if sum(1 for (_, sd), v in vs.items() if sd == seed and v["s64"] is not None and v["s64"] >= 10.0) >= 2]
        print(
            f"| {c} | {sum(v['ok'] for v in vs.values())}/{len(vs)} | " + " | ".join(met)
            + f" | {geometric_mean([v['ratio'] for v in vs.values()]):.2f} | {sum(v['ratio'] <= 1.0 for v in vs.values())}/{len(vs)} | {len(ten)}/{len(seeds)} |"
        )
    print()
    print("Median over seeds, scene by scene: settled error over Adam-3's, speed-up to Adam-3's goal, speed-up to Adam-64's goal:\n")
    print("| configuration | " + " | ".join(scenes) + " |")
    print("|---|" + "---|" * len(scenes))
    # A speed-up of None (neither run reaches the goal) counts as 0, as "never" does.
    med = lambda xs: statistics.median(x if x is not None else 0.0 for x in xs)
    for c in runs:
        cells = [
            f"{med(v['ratio'] for v in mine):.2f}, {med(v['s3'] for v in mine):.1f}×, {med(v['s64'] for v in mine):.1f}×" if mine else "-"
            for mine in per_scene[c].values()
        ]
        print(f"| {c} | " + " | ".join(cells) + " |")
    print()
    if edges:
        print("The best Adam-3 ran at an end of its grid (a wider grid may hold a better rate) at seeds: "
              + "; ".join(f"{s} {', '.join(e)}" for s, e in edges.items()) + ".\n")


USAGE = "usage: results.py [--pilot | --depth | --goals | --seeds] [--costs OUTDIR]... OUTDIR [OUTDIR ...]"


def main():
    args = sys.argv[1:]
    mode = protocol
    modes = {"--pilot": pilot, "--depth": depth, "--goals": goals, "--seeds": seeds}
    if args and args[0] in modes:
        mode, args = modes[args[0]], args[1:]
    cost_dirs = []
    while len(args) >= 2 and args[0] == "--costs":
        cost_dirs.append(args[1])
        args = args[2:]
    if not args or any(a.startswith("--") for a in args):
        sys.exit(USAGE)
    by_scene = load(args)
    if cost_dirs:
        by_scene = priced(by_scene, costs_of(load(cost_dirs)))
    mode(by_scene)


if __name__ == "__main__":
    main()
