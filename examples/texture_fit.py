"""What the texture-fitting examples share: the glossy scene, its true roughness texture,
the target image, and the command line's --iterations and --film."""

import argparse
from pathlib import Path

import numpy as np

import vkinverse as vk

ROOT = Path(__file__).resolve().parents[1]
NAME = "materials.metal.roughness"
START = 0.4


def setup(description):
    """(args, scene, true texture, target image) for a fit of the roughness texture."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--iterations", type=int, default=150)
    ap.add_argument("--film", type=int, default=64)
    args = ap.parse_args()
    scene = vk.Scene(ROOT / "scenes/glossy/scene.toml", film=(args.film, args.film))
    truth = np.array(scene.params[NAME])
    target = np.array(vk.render(scene, spp=512, seed=1))
    return args, scene, truth, target


def report(it, iterations, loss, texture, truth):
    if it % 25 == 0 or it == iterations - 1:
        print(f"iteration {it}: loss {loss:.4g}, texture RMSE {np.sqrt(np.mean((np.asarray(texture) - truth) ** 2)):.4f}")


def finish(texture, truth):
    start = np.sqrt(np.mean((START - truth) ** 2))
    end = float(np.sqrt(np.mean((np.asarray(texture) - truth) ** 2)))
    print(f"roughness texture RMSE {start:.4f} -> {end:.4f}")
    assert end < start, "the texture did not move towards the truth"
