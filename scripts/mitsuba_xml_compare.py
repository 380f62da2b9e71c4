#!/usr/bin/env python3
"""Renders one Mitsuba 3 XML scene in Mitsuba (variant llvm_ad_rgb) and in vkinverse
straight from the same file, and compares the images against both renderers' Monte Carlo
noise (two independent renders each; statistics of scripts/mitsuba_compare.py).

    python3 scripts/mitsuba_xml_compare.py scenes/mitsuba/scene.xml --spp 256 --res 64 256 --out /tmp/xmlcmp

The scene takes its film size from a `res` default (width and height "$res"), which
Mitsuba gets as a parameter and vkinverse as `--film RESxRES`. Reported per resolution:
each channel's image mean in both with the z-score of their difference, the block
z-scores (8 x 8 pixels) and where the worst block is (those nearly free of noise, an
emitter or the sky seen directly, counted apart), mean relative errors against the
noise, and the render times (Mitsuba's up to the image read back). vkinverse's import
warnings (where its mapping of the scene is approximate) are printed first.

Mitsuba is a peer to measure against, not a dependency: it is imported only here.
Needs `pip install mitsuba numpy` and Debian's libllvm19.
"""

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba_compare as mc  # noqa: E402  (shared helpers: Mitsuba set-up, vkinverse runs, statistics)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--vkinverse", help="vkinverse binary (default: target/release/vkinverse)")
    args = ap.parse_args()
    np, dr, mi = mc.import_mitsuba()
    vk = mc.find_vkinverse(args.vkinverse)
    args.out.mkdir(parents=True, exist_ok=True)
    scene_path = args.scene.resolve()
    results = {"scene": str(args.scene), "spp": args.spp, "resolutions": {}}
    for res in args.res:
        out = args.out / f"{res}"
        out.mkdir(exist_ok=True)
        scene = mi.load_file(str(scene_path), res=res)

        def mitsuba_render(seed):
            t = time.perf_counter()
            img = np.array(mi.render(scene, spp=args.spp, seed=seed))  # read back: synchronous
            return time.perf_counter() - t, img

        mitsuba_render(0)  # compiles the kernels
        m = [mitsuba_render(s) for s in (1, 2)]
        film = f"{res}x{res}"
        _, _, warnings = mc.run_vk(vk, ["render", scene_path, "--film", film, "--spp", 1, "-o", out / "vk_warmup.exr"])
        if res == args.res[0]:
            print(warnings.strip())
        v = []
        for s in (1, 2):
            path = out / f"vkinverse_seed{s}.exr"
            dt, _, err = mc.run_vk(vk, ["render", scene_path, "--film", film, "--spp", args.spp, "--seed", s, "--quiet", "-o", path])
            v.append((dt, np.array(mi.Bitmap(str(path)))[..., :3]))
        for s, (_, img) in zip((1, 2), m):
            mi.util.write_bitmap(str(out / f"mitsuba_seed{s}.exr"), img, write_async=False)
        cmp = mc.image_comparison(np, m[0][1], m[1][1], v[0][1], v[1][1])
        cmp.pop("_z", None)
        cmp["mitsuba_s"] = [t for t, _ in m]
        cmp["vkinverse_s"] = [t for t, _ in v]
        results["resolutions"][res] = cmp
        b = cmp["blocks"]
        print(f"\n{res}x{res}, {args.spp} spp")
        for c, ch in zip("rgb", cmp["channel_means"]):
            print(f"  {c}: mitsuba {ch['mitsuba']:.5f}  vkinverse {ch['vkinverse']:.5f}  "
                  f"diff {ch['diff'] / ch['vkinverse'] * 100:+.2f} %  z {ch['z']:+.2f}")
        infl = cmp["block_variance_inflation"]
        print(f"  block variance over the sum of its pixels' (correlated pixels, e.g. a splatting filter): "
              f"mitsuba {infl['mitsuba']:.2f}, vkinverse {infl['vkinverse']:.2f}")
        print(f"  blocks: {b['abs_z_over_4']} of {b['count']} beyond 4 se, max |z| {b['max_abs_z']:.2f} "
              f"(worst at row {b['worst']['row']}, col {b['worst']['col']}, {b['worst']['channel']}: "
              f"{b['worst']['relative_diff'] * 100:+.1f} %)")
        nb, qb = b["noisy"], b["quiet"]
        print(f"  of which noisy blocks: {nb['abs_z_over_4']} of {nb['count']}, max |z| {nb['max_abs_z']:.2f}; "
              f"quiet blocks (standard error < {mc.QUIET:g} of the mean, e.g. an emitter or the sky seen directly): "
              f"{qb['abs_z_over_4']} of {qb['count']}, relative difference {qb['median_relative_diff'] * 100:.3f} % "
              f"in the median, {qb['max_relative_diff'] * 100:.2f} % at most")
        print(f"  mean relative error {cmp['mre_mitsuba_vs_vkinverse']:.4f} vs {cmp['mre_expected_if_equal']:.4f} "
              f"expected from noise alone")
        print(f"  time: mitsuba {min(cmp['mitsuba_s']):.2f} s, vkinverse {min(cmp['vkinverse_s']):.2f} s (process)")
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    print(f"\nresults in {args.out / 'results.json'}")


if __name__ == "__main__":
    main()
