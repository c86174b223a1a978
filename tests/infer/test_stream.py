"""Streaming inference equals batch prediction on every prefix (tiny random models)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from imaging_factory import (
    HALF_MM,
    RADIUS_MM,
    tiny_imager,
)

from lesscli.data.batching import ScanDataset, collate
from lesscli.infer.stream import StreamingImager
from lesscli.models.imager import Imager
from lesscli.types import ImageGrid

LOGIT_TOL = 1e-4


def edge_sequence(n_random: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Poses (n, 6) and raw forces (n, 30, 3): random touches plus hand-placed edge cases.

    Edge cases: on the outermost particle (grid corner and edge), exactly one radius from a particle
    (strictly outside its field), just inside a radius beyond the grid edge, and far outside every field.
    """
    special = [(HALF_MM, HALF_MM), (HALF_MM, 0.0), (-HALF_MM, -HALF_MM), (HALF_MM + RADIUS_MM, 0.0),
               (0.0, -HALF_MM - RADIUS_MM + 1e-3), (45.0, 45.0), (-60.0, 3.0), (0.0, HALF_MM + RADIUS_MM)]
    xy = np.concatenate([rng.uniform(-32, 32, (n_random, 2)), np.array(special)])
    order = rng.permutation(len(xy))
    xy = xy[order]
    n = len(xy)
    pose = np.zeros((n, 6), np.float32)
    pose[:, :2] = xy
    pose[:, 2] = -rng.uniform(0, 4, n)
    pose[:, 3:5] = rng.normal(0, 0.05, (n, 2))
    pose[:, 5] = rng.uniform(0, 1.4, n)
    force = rng.normal(0, 0.5, (n, 30, 3)).astype(np.float32)
    force[..., 2] += -pose[:, 2:3]
    return pose, force


def batch_logits(imager: Imager, stats: dict, pose: np.ndarray, force: np.ndarray, k: int) -> torch.Tensor:
    """Batch prediction on the first k samples, normalised exactly as ScanDataset does."""
    mean, std = np.asarray(stats["force_mean"]), np.asarray(stats["force_std"])
    f = ((force[:k].reshape(k, -1).astype(np.float64) - mean) / std).astype(np.float32)
    item = {"pose": torch.from_numpy(np.ascontiguousarray(pose[:k], np.float32)),
            "force": torch.from_numpy(f), "scan_index": 0}
    with torch.no_grad():
        return imager(collate([item]))[0]


CASES = [{"dim": 2}, {"dim": 3}, {"dim": 2, "cap": 3}, {"dim": 3, "cap": 2},
         {"dim": 2, "encoder": "global"}, {"dim": 2, "encoder": "global", "cap": 4},
         {"dim": 3, "encoder": "global-taxel"}, {"dim": 2, "encoder": "global-taxel", "cap": 4},
         {"dim": 2, "stitch": "mean"}, {"dim": 3, "cap": 3, "stitch": "mean"},
         {"dim": 2, "context": 3}, {"dim": 3, "cap": 3, "context": 5, "stitch": "mean"}]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(f"{k}{v}" for k, v in c.items()))
def test_stream_matches_batch_on_prefixes(case):
    imager, stats, _ = tiny_imager(**case)
    rng = np.random.default_rng(7)
    pose, force = edge_sequence(40, rng)
    stream = StreamingImager(imager, stats)
    checkpoints = {1, 2, 5, 17, 31, len(pose)}
    checked = 0
    for i in range(len(pose)):
        stream.push(pose[i], force[i])
        if i + 1 in checkpoints:
            diff = (stream.logits() - batch_logits(imager, stats, pose, force, i + 1)).abs().max()
            assert float(diff) <= LOGIT_TOL, f"prefix {i + 1}: max |logit diff| {float(diff):.2e}"
            checked += 1
    assert checked == len(checkpoints)
    assert stream.n_steps == len(pose)


def test_edge_samples_advance_exactly_the_particles_in_field():
    imager, stats, _ = tiny_imager()
    stream = StreamingImager(imager, stats)
    force = np.zeros((30, 3), np.float32)
    xy = stream.xy_mm.numpy()

    def advanced(x, y):
        return sorted(stream.push(np.array([x, y, -1, 0, 0, 0]), force).tolist())

    corner = int(np.argmin(((xy - [HALF_MM, HALF_MM]) ** 2).sum(1)))
    assert corner in advanced(HALF_MM, HALF_MM)
    assert advanced(HALF_MM + RADIUS_MM, 0.0) == []            # exactly one radius away: outside (strict)
    assert advanced(50.0, 50.0) == []                          # beyond every field
    before = stream.logits().clone()
    assert advanced(-70.0, 0.0) == []
    assert torch.equal(stream.logits(), before)                # an out-of-field sample changes nothing
    near = advanced(HALF_MM + RADIUS_MM - 0.5, 0.0)
    assert near == [int(np.argmin(((xy - [HALF_MM, 0.0]) ** 2).sum(1)))]


def test_untouched_image_is_uniform_and_only_nearby_pixels_change():
    imager, stats, _ = tiny_imager()
    stream = StreamingImager(imager, stats)
    assert float(stream.logits().abs().max()) == 0.0
    ent = stream.entropy()
    assert np.allclose(ent, math.log(4), atol=1e-6)
    stream.push(np.array([-12.0, -12.0, -2, 0, 0, 0]), np.ones((30, 3)))
    changed = (stream.logits().abs() > 0).any(0)[0].numpy()     # (H, W)
    rows, cols = np.nonzero(changed)
    grid = stream.grid
    x = grid.origin_mm[2] + cols * grid.spacing_mm[2]
    y = grid.origin_mm[1] + rows * grid.spacing_mm[1]
    # field + half a patch (8 px of 1 mm) + a pixel
    reach = RADIUS_MM + 4 * 1.0 + 1.0
    assert changed.any() and np.hypot(x + 12, y + 12).max() <= reach * math.sqrt(2)
    assert not changed[:, -10:].any()                           # the far side stays untouched


def test_cap_freezes_particles_after_their_earliest_steps():
    imager, stats, _ = tiny_imager(cap=2)
    stream = StreamingImager(imager, stats)
    pose = np.array([0.0, 0.0, -1, 0, 0, 0])
    first = stream.push(pose, np.ones((30, 3)))
    stream.push(pose, np.ones((30, 3)))
    frozen = stream.logits().clone()
    assert stream.push(pose, 5 * np.ones((30, 3))).numel() == 0
    assert torch.equal(stream.logits(), frozen)
    assert (stream.count[first] == 2).all()


def test_resampled_grid_matches_batch():
    grid = ImageGrid((1, 30, 30), (0.0, -29.0, -29.0), (0.9, 2.0, 2.0))   # patches resampled to 2 mm pixels
    imager, stats, _ = tiny_imager(grid=grid)
    pose, force = edge_sequence(20, np.random.default_rng(3))
    stream = StreamingImager(imager, stats)
    for i in range(len(pose)):
        stream.push(pose[i], force[i])
    diff = (stream.logits() - batch_logits(imager, stats, pose, force, len(pose))).abs().max()
    assert float(diff) <= LOGIT_TOL


@pytest.mark.parametrize("dim,stitch", [(2, "sum"), (3, "sum"), (2, "mean")])
def test_patches_partly_and_wholly_off_the_grid_match_batch(dim, stitch):
    """A grid covering x, y in [-5, 14] mm: the patches of particles at -18 and -12 mm lie wholly off it,
    those at -6, 12 and 18 mm partly."""
    grid = ImageGrid((3 if dim == 3 else 1, 20, 20), (-1.8 if dim == 3 else 0.0, -5.0, -5.0), (0.9, 1.0, 1.0))
    imager, stats, _ = tiny_imager(dim=dim, grid=grid, stitch=stitch)
    pose, force = edge_sequence(20, np.random.default_rng(4))
    stream = StreamingImager(imager, stats)
    for i in range(len(pose)):
        stream.push(pose[i], force[i])
    assert bool(stream.seen[0]) and bool(stream.seen[-1])             # particles at (-18, -18) and (18, 18)
    diff = (stream.logits() - batch_logits(imager, stats, pose, force, len(pose))).abs().max()
    assert float(diff) <= LOGIT_TOL


def test_reset_and_bad_sizes():
    from lesscli.errors import DataError

    imager, stats, _ = tiny_imager()
    stream = StreamingImager(imager, stats)
    stream.push(np.array([0.0, 0, -1, 0, 0, 0]), np.ones((30, 3)))
    stream.reset()
    assert stream.n_steps == 0 and float(stream.logits().abs().max()) == 0.0
    with pytest.raises(DataError, match="expects 90"):
        stream.push(np.zeros(6), np.ones((29, 3)))
    with pytest.raises(DataError, match="expected 6"):
        stream.push(np.zeros(5), np.ones((30, 3)))


def test_matches_scan_dataset_normalisation():
    from factories import random_scanset

    imager, stats, _ = tiny_imager()
    scans = random_scanset(n_scans=1, traj_per_scan=4, max_len=6, seed=2, with_labels=False)
    item = ScanDataset(scans, stats)[0]
    stream = StreamingImager(imager, stats)
    for i in range(scans.n_steps):
        stream.push(scans.pose[i], scans.force[i])
    with torch.no_grad():
        expected = imager(collate([item]))[0]
    assert float((stream.logits() - expected).abs().max()) <= LOGIT_TOL


@pytest.mark.parametrize("case", [{"dim": 2}, {"dim": 3, "cap": 3}, {"dim": 2, "encoder": "global"}],
                         ids=["2d", "3d-cap", "global"])
def test_prime_then_deferred_pushes_match_batch(case):
    imager, stats, _ = tiny_imager(**case)
    pose, force = edge_sequence(30, np.random.default_rng(11))
    stream = StreamingImager(imager, stats, defer_decode=True)
    stream.prime(pose[:12], force[:12])
    assert float((stream.logits() - batch_logits(imager, stats, pose, force, 12)).abs().max()) <= LOGIT_TOL
    for i in range(12, len(pose)):
        stream.push(pose[i], force[i])
        if i % 7 == 0:
            k = i + 1
            assert (float((stream.logits() - batch_logits(imager, stats, pose, force, k)).abs().max())
                    <= LOGIT_TOL)
    assert stream.dirty.any() or case.get("cap")     # the last pushes are still waiting to be decoded
    assert (float((stream.logits() - batch_logits(imager, stats, pose, force, len(pose))).abs().max())
            <= LOGIT_TOL)
    assert stream.flush() == 0                       # reading the image flushed every deferred decode
