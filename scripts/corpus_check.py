#!/usr/bin/env python3
"""Imports other people's scenes as they are: every Mitsuba XML scene and glTF/GLB model
under the given directories is rendered by vkinverse, unmodified, and the outcome tabled:
rendered, refused (with vkinverse's one-line reason), crashed or timed out. With
--mitsuba, each XML scene that renders is also rendered by Mitsuba 3 (llvm_ad_rgb) and the
image means compared against both renderers' noise.

    python3 scripts/corpus_check.py --out /tmp/corpus ~/mitsuba-data/docs/scenes \\
        ~/mitsuba-data/scenes ~/glTF-Sample-Models/2.0 --mitsuba

Point it at a checkout of mitsuba-data (its docs/scenes, scenes/cbox, scenes/matpreview,
scenes/hello.xml) and of the Khronos glTF sample models. Files in directories named
`include` or `fragments` are parts of other scenes and are skipped. Films are scaled so
that the longer side is --res pixels (in a temporary copy of the XML beside the original,
so that its relative paths hold). The table (Markdown) goes to stdout and DIR/corpus.md;
each file's details to DIR/corpus.json.

Mitsuba is a peer to measure against, not a dependency: it is imported only here, with
--mitsuba. Needs `pip install mitsuba numpy` and Debian's libllvm19.
"""

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

SKIP_DIRS = {"include", "fragments"}


def scenes(roots):
    out = []
    for root in roots:
        root = Path(root)
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.suffix.lower() in (".xml", ".gltf", ".glb"))
        for f in files:
            if SKIP_DIRS & set(f.parts):
                continue
            if f.suffix.lower() == ".xml" and "<scene" not in f.read_text(errors="replace")[:4000]:
                continue
            if f.name.endswith(".corpus.xml"):
                continue
            out.append(f)
    return out


def scaled_copy(path, res, depth=0):
    """A copy of the XML beside it with every film's width and height scaled so that the
    longer side is `res` (the values may be `$defaults`: those are resolved first). A film
    in an included file is scaled in a copy of that file, which the copy includes instead."""
    text = path.read_text()
    if depth < 4 and not re.search(r"<film\b", text):
        def scaled_include(m):
            included = path.parent / m.group(2)
            if not included.is_file() or not re.search(r"<film\b", included.read_text(errors="replace")):
                return m.group(0)
            copy = scaled_copy(included, res, depth + 1)
            return m.group(1) + str(Path(m.group(2)).with_name(copy.name)) + m.group(3)

        text = re.sub(r'(<include\s+filename=")([^"]+)(")', scaled_include, text)
    defaults = dict(re.findall(r'<default\s+name="([^"]+)"\s+value="([^"]+)"', text))

    def value(v):
        v = defaults.get(v[1:], v) if v.startswith("$") else v
        # A default that another file sets (one that includes this one): scaled to res.
        return res if v.startswith("$") else int(float(v))

    film = re.search(r"<film\b.*?</film>", text, re.S)
    if film:
        body = film.group(0)
        w = re.search(r'<integer\s+name="width"\s+value="([^"]+)"', body)
        h = re.search(r'<integer\s+name="height"\s+value="([^"]+)"', body)
        width, height = (value(w.group(1)) if w else 768), (value(h.group(1)) if h else 576)
        scale = res / max(width, height)
        nw, nh = max(1, round(width * scale)), max(1, round(height * scale))
        new = re.sub(r'(<integer\s+name="width"\s+value=")[^"]+', rf"\g<1>{nw}", body)
        new = re.sub(r'(<integer\s+name="height"\s+value=")[^"]+', rf"\g<1>{nh}", new)
        if not w:
            new = new.replace(">", f'><integer name="width" value="{nw}"/>', 1)
        if not h:
            new = new.replace(">", f'><integer name="height" value="{nh}"/>', 1)
        text = text[: film.start()] + new + text[film.end():]
    copy = path.with_name(path.stem + ".corpus.xml")
    copy.write_text(text)
    return copy


def run_vkinverse(vk, scene, out, spp, seed, timeout, film=None):
    cmd = [vk, "render", str(scene), "--spp", str(spp), "--seed", str(seed), "-o", str(out), "--quiet"]
    if film:
        cmd += ["--film", film]
    t0 = time.time()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", f"no result in {timeout} s", time.time() - t0
    secs = time.time() - t0
    lines = [l for l in (p.stderr + p.stdout).splitlines() if l.strip()]
    if p.returncode == 0:
        return "rendered", " | ".join(l for l in lines if "warning" in l.lower())[:300], secs
    if p.returncode in (1, 2):
        return "refused", (lines[-1] if lines else "")[:300], secs
    return "crashed", f"exit {p.returncode}: " + (lines[-1] if lines else "")[:300], secs


def read_exr(np, path):
    import mitsuba as mi

    return np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3]


def compare(np, a1, a2, b1, b2):
    """Mean per channel of a (vkinverse) and b (Mitsuba), and the z-score of their
    difference, the noise estimated from each renderer's two independent images."""
    ma, mb = (a1 + a2).mean(axis=(0, 1)) / 2, (b1 + b2).mean(axis=(0, 1)) / 2
    n = a1.shape[0] * a1.shape[1]
    sa = np.sqrt(((a1 - a2) ** 2).mean(axis=(0, 1)) / 4 / n)
    sb = np.sqrt(((b1 - b2) ** 2).mean(axis=(0, 1)) / 4 / n)
    z = (ma - mb) / np.maximum(np.sqrt(sa**2 + sb**2), 1e-9)
    return ma, mb, z


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("roots", nargs="+")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--vkinverse", default="target/release/vkinverse")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--timeout", type=int, default=300)
    ap.add_argument("--mitsuba", action="store_true", help="compare the XML scenes that render with Mitsuba's images")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.mitsuba:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
        import mitsuba as mi
        import numpy as np

        mi.set_variant("llvm_ad_rgb")
    rows = []
    for i, scene in enumerate(scenes(args.roots)):
        xml = scene.suffix.lower() == ".xml"
        src = scaled_copy(scene, args.res) if xml else scene
        film = None if xml else f"{args.res}x{args.res}"
        row = {"file": str(scene)}
        try:
            imgs = [args.out / f"{i:03d}-vk{s}.exr" for s in (1, 2)]
            row["outcome"], row["message"], row["seconds"] = run_vkinverse(args.vkinverse, src, imgs[0], args.spp, 1, args.timeout, film)
            if args.mitsuba and xml and row["outcome"] == "rendered":
                try:
                    run_vkinverse(args.vkinverse, src, imgs[1], args.spp, 2, args.timeout, film)
                    a1, a2 = read_exr(np, imgs[0]), read_exr(np, imgs[1])
                    m = mi.load_file(str(src))
                    b1, b2 = (np.array(mi.render(m, spp=args.spp, seed=s), dtype=np.float64)[..., :3] for s in (1, 2))
                    if a1.shape != b1.shape:
                        row["mitsuba"] = f"film {a1.shape[:2]} vs Mitsuba's {b1.shape[:2]}"
                    else:
                        ma, mb, z = compare(np, a1, a2, b1, b2)
                        row["mean"], row["mitsuba_mean"], row["z"] = ma.tolist(), mb.tolist(), z.tolist()
                        row["agrees"] = bool(np.all(np.abs(z) < 4) or np.allclose(ma, mb, rtol=0.02, atol=1e-4))
                except Exception as e:  # Mitsuba refusing a scene is a finding too
                    row["mitsuba"] = f"Mitsuba: {str(e).splitlines()[0][:200]}"
        finally:
            if xml:
                src.unlink(missing_ok=True)
        rows.append(row)
        print(f"{row['outcome']:9s} {scene}: {row.get('message', '')[:120]}", file=sys.stderr)
    (args.out / "corpus.json").write_text(json.dumps(rows, indent=1))
    counts = {}
    for r in rows:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    lines = [f"{len(rows)} files: " + ", ".join(f"{n} {k}" for k, n in sorted(counts.items())), ""]
    compared = [r for r in rows if "agrees" in r]
    if args.mitsuba:
        lines += [f"Compared with Mitsuba: {len(compared)}; agree within noise: {sum(r['agrees'] for r in compared)}", ""]
    lines += ["| file | outcome | vkinverse says | Mitsuba |", "|---|---|---|---|"]
    for r in rows:
        mit = ""
        if "agrees" in r:
            ratio = [a / b if b else float("nan") for a, b in zip(r["mean"], r["mitsuba_mean"])]
            mit = ("agrees" if r["agrees"] else "differs") + " (mean ratio " + ", ".join(f"{x:.3f}" for x in ratio) + ")"
        elif "mitsuba" in r:
            mit = r["mitsuba"]
        msg = r.get("message", "").replace("|", "/")
        lines.append(f"| {r['file']} | {r['outcome']} | {msg} | {mit} |")
    table = "\n".join(lines)
    (args.out / "corpus.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
