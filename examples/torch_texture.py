"""Fits the glossy scene's 8 x 8 roughness texture with PyTorch: an image-space loss plus a
smoothness prior on the texture, differentiated through vkinverse's renderer.

    python3 examples/torch_texture.py [--iterations 150] [--film 64]
"""

import argparse
from pathlib import Path

import numpy as np
import torch

import vkinverse as vk
import vkinverse.torch as vkt

ROOT = Path(__file__).resolve().parents[1]
NAME = "materials.metal.roughness"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=150)
    ap.add_argument("--film", type=int, default=64)
    args = ap.parse_args()
    scene = vk.Scene(ROOT / "scenes/glossy/scene.toml", film=(args.film, args.film))
    truth = np.array(scene.params[NAME])
    target = torch.from_numpy(np.array(vk.render(scene, spp=512, seed=1)))
    rough = torch.full(truth.shape, 0.4, requires_grad=True)
    opt = torch.optim.Adam([rough], lr=0.03)
    lo, hi = scene.params.range(NAME)
    for it in range(args.iterations):
        opt.zero_grad()
        image = vkt.render(scene, {NAME: rough}, spp=4, seed=2 * it + 10, grad_spp=4)
        smooth = (rough[1:] - rough[:-1]).pow(2).mean() + (rough[:, 1:] - rough[:, :-1]).pow(2).mean()
        loss = (image - target).pow(2).mean() + 1e-3 * smooth
        loss.backward()
        opt.step()
        with torch.no_grad():
            rough.clamp_(lo, hi)
        if it % 25 == 0 or it == args.iterations - 1:
            print(f"iteration {it}: loss {loss.item():.4g}, texture RMSE {np.sqrt(np.mean((rough.detach().numpy() - truth) ** 2)):.4f}")
    start = np.sqrt(np.mean((0.4 - truth) ** 2))
    end = np.sqrt(np.mean((rough.detach().numpy() - truth) ** 2))
    print(f"roughness texture RMSE {start:.4f} -> {end:.4f}")
    assert end < start, "the texture did not move towards the truth"


if __name__ == "__main__":
    main()
