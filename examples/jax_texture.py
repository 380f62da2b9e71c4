"""Fits the glossy scene's 8 x 8 roughness texture with JAX: an image-space loss plus a
smoothness prior on the texture, differentiated (jax.grad) through vkinverse's renderer,
stepped by a few lines of Adam.

    python3 examples/jax_texture.py [--iterations 150] [--film 64]
"""

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import vkinverse as vk
import vkinverse.jax as vkj

ROOT = Path(__file__).resolve().parents[1]
NAME = "materials.metal.roughness"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=150)
    ap.add_argument("--film", type=int, default=64)
    args = ap.parse_args()
    scene = vk.Scene(ROOT / "scenes/glossy/scene.toml", film=(args.film, args.film))
    truth = np.array(scene.params[NAME])
    target = jnp.asarray(vk.render(scene, spp=512, seed=1))
    lo, hi = scene.params.range(NAME)

    def loss(rough, it):
        image = vkj.render(scene, {NAME: rough}, spp=4, seed=2 * it + 10, grad_spp=4)
        smooth = jnp.mean((rough[1:] - rough[:-1]) ** 2) + jnp.mean((rough[:, 1:] - rough[:, :-1]) ** 2)
        return jnp.mean((image - target) ** 2) + 1e-3 * smooth

    rough = jnp.full(truth.shape, 0.4, dtype=jnp.float32)
    m, v = jnp.zeros_like(rough), jnp.zeros_like(rough)
    for it in range(args.iterations):
        value, g = jax.value_and_grad(loss)(rough, it)
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
        step = 0.03 * (m / (1 - 0.9 ** (it + 1))) / (jnp.sqrt(v / (1 - 0.999 ** (it + 1))) + 1e-8)
        rough = jnp.clip(rough - step, lo, hi)
        if it % 25 == 0 or it == args.iterations - 1:
            print(f"iteration {it}: loss {float(value):.4g}, texture RMSE {float(jnp.sqrt(jnp.mean((rough - truth) ** 2))):.4f}")
    start = np.sqrt(np.mean((0.4 - truth) ** 2))
    end = float(jnp.sqrt(jnp.mean((rough - truth) ** 2)))
    print(f"roughness texture RMSE {start:.4f} -> {end:.4f}")
    assert end < start, "the texture did not move towards the truth"


if __name__ == "__main__":
    main()
