"""Fits the glossy scene's 8 x 8 roughness texture with PyTorch: an image-space loss plus a
smoothness prior on the texture, differentiated through vkinverse's renderer.

    python3 examples/torch_texture.py [--iterations 150] [--film 64]
"""

import torch

import vkinverse.torch as vkt
from texture_fit import NAME, START, finish, report, setup


def main():
    args, scene, truth, target = setup(__doc__.splitlines()[0])
    target = torch.from_numpy(target)
    rough = torch.full(truth.shape, START, requires_grad=True)
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
        report(it, args.iterations, loss.item(), rough.detach().numpy(), truth)
    finish(rough.detach().numpy(), truth)


if __name__ == "__main__":
    main()
