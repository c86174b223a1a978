"""Scan sets as torch datasets: one item per scan, padded batches, force normalisation.

Normalisation statistics are computed once from the training set (:func:`compute_norm_stats`),
stored in the checkpoint, and reused unchanged for validation, test and inference data.
"""

from __future__ import annotations

import numpy as np
import torch

from lesscli.errors import DataError
from lesscli.io.scans import ScanSet
from lesscli.types import Batch

# Force features whose standard deviation is below this are only centred, not scaled.
STD_FLOOR = 1e-8


NORM_MODES = ("global", "feature", "scale")


def compute_norm_stats(scans: ScanSet, mode: str = "global") -> dict:
    """Force mean per feature and a scale, over every step of a (training) scan set.

    Args:
        scans: the training scan set.
        mode: ``global`` (default): one standard deviation pooled over all features, so the
            normalised MSE stays proportional to the physical squared error and channels that only
            carry sensor noise (e.g. shear of a shear-free sensor) keep their small weight;
            ``feature``: one standard deviation per feature; ``scale``: no centring, one scale per
            taxel (the root mean square of its normal force, axis 2) for its three axes: zero force
            stays 0, and each taxel's own gain and place in the pad's pressure profile (rim taxels of
            a flat pad read many times the centre ones) is divided out, a flat field.

    Returns:
        ``{"force_mean": [F floats], "force_std": [F floats], "mode": str, "n_steps": int,
        "force_units": str}`` with F = taxels x 3; a standard deviation below ``STD_FLOOR`` is
        stored as 1.
    """
    if mode not in NORM_MODES:
        raise DataError(f"force normalisation '{mode}' is unknown (choices: {', '.join(NORM_MODES)})")
    if scans.n_steps == 0:
        raise DataError("training scan set has no steps: cannot compute normalisation statistics")
    flat = scans.force.reshape(scans.n_steps, -1).astype(np.float64)
    if mode == "scale":
        normal = scans.force[..., 2].astype(np.float64)
        mean, var = np.zeros(flat.shape[1]), np.repeat((normal * normal).mean(axis=0), 3)
    else:
        mean, var = flat.mean(axis=0), flat.var(axis=0)
    std = np.sqrt(var) if mode in ("feature", "scale") else np.full_like(var, np.sqrt(var.mean()))
    std = np.where(std > STD_FLOOR, std, 1.0)
    units = scans.meta.get("units", {}).get("force", "") if isinstance(scans.meta, dict) else ""
    return {"force_mean": mean.tolist(), "force_std": std.tolist(), "mode": mode,
            "n_steps": int(scans.n_steps), "force_units": str(units)}


def normalise_forces(force: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Raw forces (n, T, 3) or (n, F) -> (n, F) float32 normalised; n may be 0 (an untouched scan)."""
    force = np.asarray(force, np.float64)
    return ((force.reshape(force.shape[0], mean.shape[0]) - mean) / std).astype(np.float32)


def force_dim(norm_stats: dict) -> int:
    """F, the number of force features the statistics describe."""
    return len(norm_stats["force_mean"])


def check_force_features(scans: ScanSet, norm_stats: dict, name: str) -> None:
    """DataError naming ``name`` unless the scans' force features match the model's statistics."""
    features = scans.n_taxels * 3
    if features != force_dim(norm_stats):
        raise DataError(f"{name}: force has {scans.n_taxels} taxels x 3 = {features} features, "
                        f"but the normalisation statistics have {force_dim(norm_stats)}")


class ScanDataset(torch.utils.data.Dataset):
    """Scan s -> ``{"pose": (n, 6), "force": (n, F) normalised, "scan_index": s}`` float32 tensors.

    Args:
        scans: the scan set.
        norm_stats: statistics from :func:`compute_norm_stats` on the training set.
        name: file name used in error messages.
    """

    def __init__(self, scans: ScanSet, norm_stats: dict, name: str = "scan set") -> None:
        check_force_features(scans, norm_stats, name)
        self.scans = scans
        self.offsets = scans.scan_step_offsets()
        self.mean = np.asarray(norm_stats["force_mean"], np.float64)
        self.std = np.asarray(norm_stats["force_std"], np.float64)

    def __len__(self) -> int:
        return self.scans.n_scans

    def __getitem__(self, s: int) -> dict:
        lo, hi = int(self.offsets[s]), int(self.offsets[s + 1])
        force = normalise_forces(self.scans.force[lo:hi], self.mean, self.std)
        return {"pose": torch.from_numpy(np.ascontiguousarray(self.scans.pose[lo:hi], np.float32)),
                "force": torch.from_numpy(force), "scan_index": int(s)}


def collate(items: list[dict]) -> Batch:
    """Pad scans to the longest in the batch (at least one step); padding is zeros with valid False."""
    length = max([1] + [int(it["pose"].shape[0]) for it in items])
    b, f = len(items), int(items[0]["force"].shape[1])
    pose = torch.zeros(b, length, 6)
    force = torch.zeros(b, length, f)
    valid = torch.zeros(b, length, dtype=torch.bool)
    for i, it in enumerate(items):
        n = int(it["pose"].shape[0])
        pose[i, :n] = it["pose"]
        force[i, :n] = it["force"]
        valid[i, :n] = True
    scan_index = torch.tensor([int(it["scan_index"]) for it in items], dtype=torch.long)
    return Batch(pose=pose, force=force, valid=valid, scan_index=scan_index)


def batches(scans: ScanSet, norm_stats: dict, batch_size: int = 2) -> list[Batch]:
    """All scans in order as a list of batches (for inference and evaluation)."""
    data = ScanDataset(scans, norm_stats)
    return [collate([data[i] for i in range(lo, min(lo + batch_size, len(data)))])
            for lo in range(0, len(data), batch_size)]
