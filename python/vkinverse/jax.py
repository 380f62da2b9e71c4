"""vkinverse renders as a differentiable JAX function (a ``jax.custom_vjp`` over host
callbacks, so it composes with ``jax.grad`` and ``jax.jit``).

    import jax, jax.numpy as jnp, vkinverse as vk, vkinverse.jax as vkj
    scene = vk.Scene("scenes/cornell/scene.toml")
    def loss(color):
        image = vkj.render(scene, {"materials.red.base_color": color}, spp=16)
        return jnp.mean((image - target) ** 2)
    g = jax.grad(loss)(jnp.array([0.5, 0.5, 0.5]))

The forward pass renders with the given values (clamped into each parameter's range); the
backward pass calls :func:`vkinverse.gradient` with the cotangent as the adjoint, with its
own samples (seed + 1). JAX is not a dependency of vkinverse.
"""

import jax
import jax.numpy as jnp
import numpy as np

import vkinverse as _vk


def render(scene, params, spp=64, seed=0, sensor=0, grad_spp=None):
    """Renders ``sensor`` of ``scene`` with ``params`` ({name: array}) as a float32 array
    [height, width, 3] that JAX differentiates with respect to the arrays."""
    names = list(params)
    spp, seed, sensor = int(spp), int(seed), int(sensor)
    grad_spp = int(grad_spp or spp)
    w, h = scene.film
    image_shape = jax.ShapeDtypeStruct((h, w, 3), jnp.float32)
    shapes = [jax.ShapeDtypeStruct(tuple(scene.params.shape(n)), jnp.float32) for n in names]

    def set_values(values):
        for name, value in zip(names, values):
            scene.params[name] = np.asarray(value, dtype=np.float32)

    def host_render(*values):
        set_values(values)
        return np.array(_vk.render(scene, spp=spp, seed=seed, sensor=sensor))

    def host_gradient(cotangent, *values):
        set_values(values)
        grads = _vk.gradient(scene, np.asarray(cotangent, dtype=np.float32), spp=grad_spp, seed=seed + 1, sensor=sensor)
        return tuple(np.array(grads[n]) for n in names)

    @jax.custom_vjp
    def f(*values):
        return jax.pure_callback(host_render, image_shape, *values)

    def fwd(*values):
        return f(*values), values

    def bwd(values, cotangent):
        return tuple(jax.pure_callback(host_gradient, tuple(shapes), cotangent, *values))

    f.defvjp(fwd, bwd)
    return f(*[jnp.asarray(params[n], dtype=jnp.float32) for n in names])
