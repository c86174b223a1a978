"""``less bench imaging``: patch stitching and the imaging loss at the paper's grid sizes.

Baselines measured in the same run: placing the patches with a Python loop over particles (the
obvious implementation that the single ``index_add`` replaces; both must agree), and plain
cross-entropy as the cheapest loss next to lambda Dice + (1 - lambda) eta Focal.
"""

from __future__ import annotations

from lesscli.bench.timing import best_time

SPACING_MM = (0.9, 0.4774, 0.4774)


def loop_placement(patches, xy_mm, grid):
    """Baseline: one particle at a time, same rounding rule as ``place_patches``."""
    import torch

    from lesscli.models.patch_decoder import padded_corners

    b, _, c, d, ph, pw = patches.shape
    _, h, w = grid.shape
    out = torch.zeros(b, c, d, h + 2 * ph, w + 2 * pw)
    for i, (row, col) in enumerate(zip(*(t.tolist() for t in padded_corners(xy_mm, grid, ph, pw)))):
        out[..., row:row + ph, col:col + pw] += patches[:, i]
    return out[..., ph:ph + h, pw:pw + w]


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
    t_vec, fast = best_time(lambda: place_patches(patches, xy, grid, SPACING_MM), repeat)
    t_loop, slow = best_time(lambda: loop_placement(patches, xy, grid), repeat)
    target = torch.randint(0, 4, (batch, *shape), generator=gen)
    t_loss, _ = best_time(lambda: imaging_loss(fast, target).total, repeat)
    t_ce, _ = best_time(lambda: torch.nn.functional.cross_entropy(fast, target), repeat)
    common = {"bench": "imaging", "dim": dim, "batch": batch, "particles": int(xy.shape[0]),
              "grid": "x".join(map(str, shape)), "repeat": repeat}
    return [
        {**common, "case": "place patches: one index_add", "seconds": t_vec, "speedup_vs_loop": t_loop / t_vec,
         "max_abs_diff_vs_loop": float((fast - slow).abs().max())},
        {**common, "case": "baseline: Python loop over particles", "seconds": t_loop, "speedup_vs_loop": 1.0},
        {**common, "case": "Dice-Focal loss", "seconds": t_loss, "ratio_vs_cross_entropy": t_loss / t_ce},
        {**common, "case": "baseline: cross-entropy", "seconds": t_ce, "ratio_vs_cross_entropy": 1.0},
    ]


def run_imaging(dims: tuple[int, ...], batch: int, repeat: int, seed: int) -> list[dict]:
    """Four rows per image dimension: stitching vectorised and by loop, Dice-Focal and cross-entropy."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    rows = []
    for dim in dims:
        rows += _case(dim, batch, repeat, gen)
    return rows
