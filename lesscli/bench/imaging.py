"""``less bench imaging``: patch stitching and the imaging loss at the paper's grid sizes.

Baselines measured in the same run: placing the patches with one ``index_add`` over all pixels (the
vectorised form autograd differentiates by itself; both must agree, values and gradients), with a
random quarter of the particles unseen as in a real batch, and plain
cross-entropy as the cheapest loss next to lambda Dice + (1 - lambda) eta Focal. Placement is timed
forward (prediction) and forward + backward (a training step's share). The decoder's fast paths are timed
against their plain forms over whole epochs (:mod:`lesscli.bench.fast_paths`).
"""

from __future__ import annotations

from lesscli.bench.timing import best_time

SPACING_MM = (0.9, 0.4774, 0.4774)
SEEN_SHARE = 0.75               # particles that saw a step (the default train benchmark: 88.5 of 121)


def index_add_placement(patches, xy_mm, grid, seen):
    """Baseline: the patches masked by ``seen`` (B, P), every pixel added to the padded image in one
    ``index_add``, same rounding rule."""
    import torch

    from lesscli.models.patch_decoder import padded_corners

    b, p, c, d, ph, pw = patches.shape
    _, h, w = grid.shape
    row0, col0 = padded_corners(xy_mm, grid, ph, pw)
    wide = w + 2 * pw
    index = ((row0[:, None, None] + torch.arange(ph)[None, :, None]) * wide
             + col0[:, None, None] + torch.arange(pw)[None, None, :]).reshape(-1)
    patches = patches * seen.to(patches.dtype)[:, :, None, None, None, None]
    values = patches.permute(0, 2, 3, 1, 4, 5).reshape(b, c, d, p * ph * pw)
    canvas = torch.zeros(b, c, d, (h + 2 * ph) * wide, dtype=values.dtype).index_add(3, index, values)
    return canvas.view(b, c, d, h + 2 * ph, wide)[..., ph:ph + h, pw:pw + w]


def _train_time(place, patches, repeat: int):
    """(seconds, gradient) of ``place(patches)`` forward and backward through a fixed random read-out."""
    import torch

    with torch.no_grad():
        shape = place(patches).shape
    weight = torch.randn(shape, generator=torch.Generator().manual_seed(0))
    leaf = patches.clone().requires_grad_(True)

    def step():
        leaf.grad = None
        (place(leaf) * weight).sum().backward()
        return leaf.grad

    return best_time(step, repeat)


def _case(dim: int, batch: int, repeat: int, gen) -> list[dict]:
    import torch

    from lesscli.models.imaging_loss import imaging_loss
    from lesscli.models.particles import particle_grid
    from lesscli.models.patch_decoder import place_patches
    from lesscli.types import ImageGrid

    shape = (26 if dim == 3 else 1, 128, 128)
    grid = ImageGrid(shape, (-(shape[0] - 1) * SPACING_MM[0], -63.5 * SPACING_MM[1], -63.5 * SPACING_MM[2]),
                     SPACING_MM)
    xy = particle_grid(60.0, 6.0)
    patches = torch.randn(batch, xy.shape[0], 4, shape[0], 32, 32, generator=gen)
    seen = torch.rand(batch, xy.shape[0], generator=gen) < SEEN_SHARE
    place = lambda x: place_patches(x, xy, grid, SPACING_MM, seen)
    baseline = lambda x: index_add_placement(x, xy, grid, seen)
    t_vec, fast = best_time(lambda: place(patches), repeat)
    t_base, slow = best_time(lambda: baseline(patches), repeat)
    t_train, grad = _train_time(place, patches, repeat)
    t_train_base, grad_base = _train_time(baseline, patches, repeat)
    target = torch.randint(0, 4, (batch, *shape), generator=gen)
    t_loss, _ = best_time(lambda: imaging_loss(fast, target).total, repeat)
    t_ce, _ = best_time(lambda: torch.nn.functional.cross_entropy(fast, target), repeat)
    common = {"bench": "imaging", "dim": dim, "batch": batch, "particles": int(xy.shape[0]),
              "grid": "x".join(map(str, shape)), "repeat": repeat}
    return [
        {**common, "case": "place patches: slice adds, own backward", "seconds": t_vec,
         "train_seconds": t_train, "speedup_vs_index_add": t_base / t_vec,
         "train_speedup_vs_index_add": t_train_base / t_train,
         "max_abs_diff_vs_index_add": float((fast - slow).abs().max()),
         "max_abs_grad_diff_vs_index_add": float((grad - grad_base).abs().max())},
        {**common, "case": "baseline: one index_add", "seconds": t_base, "train_seconds": t_train_base,
         "speedup_vs_index_add": 1.0, "train_speedup_vs_index_add": 1.0},
        {**common, "case": "Dice-Focal loss", "seconds": t_loss, "ratio_vs_cross_entropy": t_loss / t_ce},
        {**common, "case": "baseline: cross-entropy", "seconds": t_ce, "ratio_vs_cross_entropy": 1.0},
    ]


def run_imaging(dims: tuple[int, ...], batch: int, repeat: int, seed: int, batches: int = 2) -> list[dict]:
    """Four rows per image dimension: stitching by slice adds and by one index_add, Dice-Focal and
    cross-entropy; then the fast paths against their plain forms, epochs of ``batches`` batches
    (:mod:`lesscli.bench.fast_paths`)."""
    import torch

    from lesscli.bench.fast_paths import run_fast_paths

    gen = torch.Generator().manual_seed(seed)
    rows = []
    for dim in dims:
        rows += _case(dim, batch, repeat, gen)
    return rows + run_fast_paths(dims, batch, batches, repeat, seed)
