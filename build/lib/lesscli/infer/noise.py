"""Pose-noise robustness: re-predict a scan set with i.i.d. Gaussian noise on the pad poses and score it.

The noise is added to every step's pose in the scan set's own frame, the phantom frame (origin at
the centre of the insert's top surface, z up): ``pose + N(0, diag(s_pos, s_pos, s_pos, s_ang,
s_ang, s_ang))`` on x, y, z (mm) and roll, pitch, yaw (rad), independently per step and per
coordinate, as in the paper's robustness experiment. Forces are left untouched. The noisy poses
change which particles see a step as well as what they see.

Common random numbers: repeat ``r`` draws one standard-normal array (N, 6) from its own stream
(spawned from ``seed``) and every cell scales that same draw by its sigmas, so differences between
cells are not blurred by different draws. The noise-free cell is deterministic and computed once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from lesscli.io.predictions import PredictionSet
from lesscli.io.scans import ScanSet
from lesscli.metrics import score_prediction_set, summarise

N_POS = 3   # x, y, z
N_ANG = 3   # roll, pitch, yaw
# Metrics kept per cell; the suffix (_3d or _2d) follows the model's image dimension.
CELL_METRICS = ("f1_micro", "f1", "com_error_mm", "diameter_error_mm")


@dataclass(frozen=True)
class NoiseLevel:
    """One cell of the sweep: standard deviations of the pose noise.

    Attributes:
        pos_mm: sigma on x, y and z, mm.
        ang_rad: sigma on roll, pitch and yaw, rad.
    """

    pos_mm: float
    ang_rad: float

    @property
    def is_zero(self) -> bool:
        return self.pos_mm == 0.0 and self.ang_rad == 0.0


def noisy_scans(scans: ScanSet, level: NoiseLevel, unit_noise: np.ndarray) -> ScanSet:
    """A copy of ``scans`` whose poses carry ``unit_noise`` scaled by the level's sigmas.

    Args:
        scans: the clean scan set (poses (N, 6): x, y, z mm, roll, pitch, yaw rad, phantom frame).
        level: the sigmas.
        unit_noise: (N, 6) standard-normal draws.

    Returns:
        ScanSet sharing everything but ``pose`` (float32) with ``scans``.
    """
    scale = np.array([level.pos_mm] * N_POS + [level.ang_rad] * N_ANG, np.float64)
    pose = (scans.pose.astype(np.float64) + unit_noise * scale).astype(np.float32)
    return replace(scans, pose=pose)


def unit_draws(n_steps: int, repeats: int, seed: int) -> list[np.ndarray]:
    """One (n_steps, 6) standard-normal array per repeat, each from its own seeded stream."""
    streams = np.random.SeedSequence(seed).spawn(repeats)
    return [np.random.default_rng(s).standard_normal((n_steps, N_POS + N_ANG)) for s in streams]


def score_cell(preds: PredictionSet, dim: int) -> dict:
    """Scalar scores of one prediction set: micro F1 over the set and means over scans."""
    suffix = "3d" if dim == 3 else "2d"
    rows = score_prediction_set(preds, cls="inclusion")
    if not rows:
        return {}
    summary = summarise(rows)[0]
    return {m: summary.get(f"{m}_{suffix}") for m in CELL_METRICS}


def _aggregate(level: NoiseLevel, scores: list[dict], repeats: int) -> dict:
    row: dict = {"pos_mm": level.pos_mm, "ang_rad": level.ang_rad, "repeats": repeats}
    for metric in CELL_METRICS:
        vals = np.array([s[metric] for s in scores if s.get(metric) is not None], np.float64)
        row[metric] = float(vals.mean()) if len(vals) else None
        row[f"{metric}_std"] = float(vals.std(ddof=1)) if len(vals) > 1 else (0.0 if len(vals) else None)
    return row


def sweep(predict_fn: Callable[[ScanSet], PredictionSet], scans: ScanSet, levels: Sequence[NoiseLevel],
          repeats: int, seed: int, dim: int, progress: Callable = lambda it, **_: it) -> list[dict]:
    """Score ``predict_fn`` on noisy copies of ``scans`` for every level and repeat.

    Args:
        predict_fn: scan set -> predictions with truth (e.g. a closure over
            :func:`lesscli.infer.predict.predict`).
        scans: clean scan set with label volumes.
        levels: the noise cells.
        repeats: noise draws per cell (the noise-free cell is computed once).
        seed: seed of the noise streams.
        dim: the model's image dimension (2 or 3), selects the 2D or 3D metrics.
        progress: wrapper for a progress bar over the predictions.

    Returns:
        one row per cell: ``pos_mm``, ``ang_rad``, ``repeats``, then for each metric of
        ``CELL_METRICS`` its mean over repeats and ``<metric>_std`` (ddof=1).
    """
    draws = unit_draws(scans.n_steps, repeats, seed)
    jobs = [(lv, r) for lv in levels for r in range(1 if lv.is_zero else repeats)]
    scores: dict[NoiseLevel, list[dict]] = {lv: [] for lv in levels}
    for level, r in progress(jobs, desc="noise cells", unit="prediction"):
        scores[level].append(score_cell(predict_fn(noisy_scans(scans, level, draws[r])), dim))
    return [_aggregate(lv, scores[lv], len(scores[lv])) for lv in levels]


def grid_levels(pos_mm: Sequence[float], ang_rad: Sequence[float]) -> list[NoiseLevel]:
    """Every combination, angle-major (one plotted line per angle level)."""
    return [NoiseLevel(float(p), float(a)) for a in ang_rad for p in pos_mm]
