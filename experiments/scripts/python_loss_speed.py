"""Time of a run on a Python loss against the same run on the built-in l2, per iteration
(the Cornell box, 20 iterations at 2 spp, primal images at 4 spp, medians of 3), for
docs/python.md. Run with the package installed: .venv/bin/python experiments/scripts/python_loss_speed.py"""
import time, numpy as np, vkinverse as vk, statistics as st
for film in (64, 256):
    scene = vk.Scene("scenes/cornell/scene.toml", film=(film, film))
    target = vk.render(scene, spp=64)
    def l2(img):
        d = img - target
        return float((d * d).mean()), (2 * d / d.size).astype(np.float32)
    for opt in ("adam", "meta"):
        py, nat = [], []
        for r in range(3):
            t = time.perf_counter(); vk.optimise(scene, optimiser=opt, iterations=20, loss=l2, quiet=True, spp=2, primal_spp=4); py.append((time.perf_counter() - t) / 20)
            res = vk.optimise(scene, optimiser=opt, iterations=20, loss="l2", quiet=True, spp=2, primal_spp=4, target_spp=64)
            nat.append(res.log["time_s"][-1] / 20)
        print(film, opt, "python %.1f ms" % (1e3 * st.median(py)), "built-in %.1f ms" % (1e3 * st.median(nat)), "ratio %.2f" % (st.median(py) / st.median(nat)))
