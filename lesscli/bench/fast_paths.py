"""The decoder's fast paths against their plain forms, a whole epoch each, in one run (``less bench
imaging``).

Each fast path sits behind one switch, a class attribute an instance may turn off: the sub-pixel
training form (``PatchDecoder.subpixel_train``, timed on an image-fit epoch on cached states, as
``image fit`` trains a frozen representation) and the sub-pixel evaluation form
(``PatchDecoder.subpixel_eval``, a prediction pass, encoder included). Each row gives both epochs' best
wall and process CPU seconds, the plain one over the fast one, and the largest differences of their
outputs and gradients on one batch (the two forms must agree).
"""

from __future__ import annotations

import copy
import math
import time

SEEN_SHARE = 0.75                # particles that saw a step, as in bench imaging's placement cases
STEPS = 400                      # steps per synthetic scan


def _grid(dim: int):
    from lesscli.bench.imaging import SPACING_MM
    from lesscli.types import ImageGrid

    shape = (26 if dim == 3 else 1, 128, 128)
    return ImageGrid(shape, (-(shape[0] - 1) * SPACING_MM[0], -63.5 * SPACING_MM[1], -63.5 * SPACING_MM[2]),
                     SPACING_MM)


def _decoder(dim: int, d_z: int, grid, seed: int):
    """The ``image fit`` default patch decoder for ``dim`` over ``grid``."""
    from lesscli.io.labels import N_CLASSES
    from lesscli.models.patch_decoder import PatchDecoder
    from lesscli.models.registry import build_decoder
    from lesscli.train.image_fit import ImageModelConfig

    image = ImageModelConfig(dim=dim)
    settings = PatchDecoder.grid_settings(grid, image.patch_px, image.stitch, image.context)
    return build_decoder({"name": "patch", "d_z": d_z, "n_classes": N_CLASSES, "dim": dim,
                          "width": image.width, **settings}, seed)


def _epochs(fast, plain, epoch, repeat: int) -> dict:
    """Best wall and process CPU seconds of ``epoch(fast)`` and ``epoch(plain)``, timed in turn after one
    warm-up each (CPU time is the steadier figure on a shared machine)."""
    epoch(fast)
    epoch(plain)
    best = {"seconds": math.inf, "plain_seconds": math.inf, "cpu_seconds": math.inf,
            "plain_cpu_seconds": math.inf}
    for _ in range(repeat):
        for net, key in ((fast, ""), (plain, "plain_")):
            wall, cpu = time.perf_counter(), time.process_time()
            epoch(net)
            best[key + "seconds"] = min(best[key + "seconds"], time.perf_counter() - wall)
            best[key + "cpu_seconds"] = min(best[key + "cpu_seconds"], time.process_time() - cpu)
    return {**best, "plain_over_fast": best["plain_seconds"] / best["seconds"],
            "plain_over_fast_cpu": best["plain_cpu_seconds"] / best["cpu_seconds"]}


def _grad_diff(a, b) -> float:
    """Largest difference of two modules' gradients (same parameters)."""
    return max(float((p.grad - q.grad).abs().max()) for p, q in zip(a.parameters(), b.parameters())
               if p.grad is not None)


def _row(case: str, switch: str, epoch: str, times: dict, **extra) -> dict:
    return {"bench": "imaging", "case": case, "switch": switch, "epoch": epoch, **times, **extra}


def _states(batch: int, d_z: int, gen):
    """Random cached states over the default particle grid, a quarter of the particles unseen."""
    import torch

    from lesscli.models.encoders import ParticleStates
    from lesscli.models.particles import particle_grid

    xy = particle_grid(60.0, 6.0)
    return ParticleStates(z=torch.randn(batch, xy.shape[0], d_z, generator=gen), xy_mm=xy,
                          seen=torch.rand(batch, xy.shape[0], generator=gen) < SEEN_SHARE)


def subpixel_train(dim: int, batch: int, batches: int, repeat: int, seed: int) -> dict:
    """An image-fit epoch on cached states (decoder forward, Dice-Focal loss, backward, Adam) with and
    without the sub-pixel training form."""
    import torch

    from lesscli.models.imaging_loss import imaging_loss

    grid, gen = _grid(dim), torch.Generator().manual_seed(seed)
    data = [(_states(batch, 128, gen), torch.randint(0, 4, (batch, *grid.shape), generator=gen))
            for _ in range(batches)]
    fast = _decoder(dim, 128, grid, seed).train()
    plain = copy.deepcopy(fast)
    plain.subpixel_train = False
    opts = {id(m): torch.optim.Adam(m.parameters(), lr=1e-4) for m in (fast, plain)}

    def epoch(net):
        for states, target in data:
            opts[id(net)].zero_grad(set_to_none=True)
            imaging_loss(net(states, grid), target).total.backward()
            opts[id(net)].step()

    logits = []
    for net in (fast, plain):
        net.zero_grad(set_to_none=True)
        logits.append(net(data[0][0], grid))
        imaging_loss(logits[-1], data[0][1]).total.backward()
    diffs = {"max_abs_diff": float((logits[0] - logits[1]).detach().abs().max()),
             "max_abs_grad_diff": _grad_diff(fast, plain)}
    times = _epochs(fast, plain, epoch, repeat)
    return _row("fast path: sub-pixel decoder training", "PatchDecoder.subpixel_train", "image fit", times,
                dim=dim, batch=batch, batches=batches, **diffs)


def subpixel_eval(dim: int, batch: int, batches: int, repeat: int, seed: int) -> dict:
    """A prediction pass (encoder and decoder, evaluation mode) with and without the sub-pixel
    evaluation form."""
    import torch

    from lesscli.bench.train import FORCE_DIM, synthetic_batch
    from lesscli.models.encoders import ParticleEncoder

    grid, gen = _grid(dim), torch.Generator().manual_seed(seed)
    data = [synthetic_batch(batch, STEPS, gen) for _ in range(batches)]
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        encoder = ParticleEncoder(FORCE_DIM, 128).eval()
    fast = _decoder(dim, 128, grid, seed).eval()
    plain = copy.deepcopy(fast)
    plain.subpixel_eval = False

    @torch.no_grad()
    def epoch(net):
        return [net(encoder(b), grid) for b in data]

    first = [epoch(net)[0] for net in (fast, plain)]
    times = _epochs(fast, plain, epoch, repeat)
    return _row("fast path: sub-pixel decoder evaluation", "PatchDecoder.subpixel_eval", "prediction", times,
                dim=dim, batch=batch, batches=batches, max_abs_diff=float((first[0] - first[1]).abs().max()))


def run_fast_paths(dims: tuple[int, ...], batch: int, batches: int, repeat: int, seed: int) -> list[dict]:
    """Two rows per image dimension, one per fast path."""
    rows = []
    for dim in dims:
        rows += [subpixel_train(dim, batch, batches, repeat, seed),
                 subpixel_eval(dim, batch, batches, repeat, seed)]
    return rows
