"""Fits the glossy scene's 8 x 8 roughness texture with JAX: an image-space loss plus a
smoothness prior on the texture, differentiated (jax.grad) through vkinverse's renderer,
stepped by a few lines of Adam.

    python3 examples/jax_texture.py [--iterations 150] [--film 64]
"""

import jax
import jax.numpy as jnp

import vkinverse.jax as vkj
from texture_fit import NAME, START, finish, report, setup


def main():
    args, scene, truth, target = setup(__doc__.splitlines()[0])
    target = jnp.asarray(target)
    lo, hi = scene.params.range(NAME)

    def loss(rough, it):
        image = vkj.render(scene, {NAME: rough}, spp=4, seed=2 * it + 10, grad_spp=4)
        smooth = jnp.mean((rough[1:] - rough[:-1]) ** 2) + jnp.mean((rough[:, 1:] - rough[:, :-1]) ** 2)
        return jnp.mean((image - target) ** 2) + 1e-3 * smooth

    rough = jnp.full(truth.shape, START, dtype=jnp.float32)
    m, v = jnp.zeros_like(rough), jnp.zeros_like(rough)
    for it in range(args.iterations):
        value, g = jax.value_and_grad(loss)(rough, it)
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
        step = 0.03 * (m / (1 - 0.9 ** (it + 1))) / (jnp.sqrt(v / (1 - 0.999 ** (it + 1))) + 1e-8)
        rough = jnp.clip(rough - step, lo, hi)
        report(it, args.iterations, float(value), rough, truth)
    finish(rough, truth)


if __name__ == "__main__":
    main()
