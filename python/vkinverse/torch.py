"""vkinverse renders as a differentiable PyTorch operation.

    import torch, vkinverse as vk, vkinverse.torch as vkt
    scene = vk.Scene("scenes/cornell/scene.toml")
    color = torch.tensor([0.5, 0.5, 0.5], requires_grad=True)
    image = vkt.render(scene, {"materials.red.base_color": color}, spp=16)
    loss = ((image - target) ** 2).mean()
    loss.backward()                      # color.grad: vkinverse's gradient estimate

The forward pass renders with the given values (set into the scene, clamped into each
parameter's range); the backward pass calls :func:`vkinverse.gradient` with the incoming
gradient as the adjoint, with its own samples (seed + 1), so that the estimate is unbiased.
Parameters not given keep the scene's values. PyTorch is not a dependency of vkinverse.
"""

import numpy as np
import torch

import vkinverse as _vk


class _Render(torch.autograd.Function):
    @staticmethod
    def forward(ctx, scene, names, spp, seed, sensor, grad_spp, *values):
        for name, value in zip(names, values):
            scene.params[name] = value.detach().cpu().numpy()
        image = _vk.render(scene, spp=spp, seed=seed, sensor=sensor)
        ctx.scene, ctx.names, ctx.seed, ctx.sensor, ctx.grad_spp = scene, names, seed, sensor, grad_spp
        ctx.save_for_backward(*values)
        return torch.from_numpy(np.array(image))

    @staticmethod
    def backward(ctx, grad_output):
        values = ctx.saved_tensors
        for name, value in zip(ctx.names, values):
            ctx.scene.params[name] = value.detach().cpu().numpy()
        grads = _vk.gradient(ctx.scene, grad_output.detach().cpu().numpy(), spp=ctx.grad_spp, seed=ctx.seed + 1, sensor=ctx.sensor)
        out = [torch.from_numpy(np.array(grads[n])).to(dtype=v.dtype, device=v.device) for n, v in zip(ctx.names, values)]
        return (None, None, None, None, None, None, *out)


def render(scene, params, spp=64, seed=0, sensor=0, grad_spp=None):
    """Renders ``sensor`` of ``scene`` with ``params`` ({name: tensor}) as a float32 tensor
    [height, width, 3] that backpropagates into the tensors (``grad_spp`` samples per pixel
    for the gradient, ``spp`` by default)."""
    names = list(params)
    values = [torch.as_tensor(params[n], dtype=torch.float32) for n in names]
    return _Render.apply(scene, names, int(spp), int(seed), int(sensor), int(grad_spp or spp), *values)
