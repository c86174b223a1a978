"""Summary records of a scan set (``less info``)."""

from __future__ import annotations

import shlex

import numpy as np

from lesscli.io.scans import ScanSet


def _stats(values: np.ndarray) -> dict:
    if values.size == 0:
        return {"min": None, "mean": None, "max": None}
    return {"min": float(values.min()), "mean": float(values.mean()), "max": float(values.max())}


OUTPUT_FLAGS = ("-o", "--output")


def _is_joined_output(word: str) -> bool:
    """``--output=X``, ``-o=X`` or ``-oX``."""
    return word.startswith(("--output=", "-o=")) or (word.startswith("-o") and not word.startswith("--") and len(word) > 2)


def _without_output(command: str) -> str:
    """A history command line without its ``-o/--output`` argument."""
    try:
        words = shlex.split(command)
    except ValueError:
        return command
    kept, skip = [], False
    for word in words:
        if skip:
            skip = False
        elif word in OUTPUT_FLAGS:
            skip = True
        elif not _is_joined_output(word):
            kept.append(word)
    return shlex.join(kept)


def history_summary(history: list[dict]) -> list[dict]:
    """History entries reduced to what made the data: command (output argument removed), version, seed.

    Where a result was written and when do not change the data, so ``less info b.npz`` and
    ``less subsample a.npz ... -o - | less info -`` print the same record.
    """
    return [{"command": _without_output(str(h.get("command", ""))), "version": h.get("version"),
             "seed": h.get("seed")} for h in history]


def describe(scans: ScanSet, path: str, full_history: bool = False) -> list[dict]:
    """One record describing ``scans``; the file name is not part of it, so pipes compare equal.

    Args:
        scans: the scan set.
        path: where it was read from (unused in the record; kept for callers).
        full_history: history entries as stored (with time and output) instead of the summary.
    """
    lengths = scans.traj_lengths()
    sensor = scans.meta.get("sensor", {})
    labels = [{"name": v.name, "shape": list(v.shape), "spacing_mm": v.spacing_mm.tolist(),
               "origin_mm": v.origin_mm.tolist(),
               "class_voxels": np.bincount(v.data.ravel(), minlength=4).tolist()} for v in scans.labels]
    per_scan = np.bincount(scans.traj_scan, minlength=scans.n_scans) if scans.n_traj else np.zeros(scans.n_scans)
    normal = scans.force[..., 2] if scans.n_steps else np.zeros(0)
    return [{
        "schema": f"{scans.meta.get('schema')}/{scans.meta.get('version')}",
        "scans": scans.n_scans, "trajectories": scans.n_traj, "steps": scans.n_steps,
        "inserts": sorted(set(scans.scan_insert.tolist())),
        "trajectories_per_scan": _stats(per_scan.astype(float)),
        "steps_per_trajectory": _stats(lengths.astype(float)),
        "pose_shape": list(scans.pose.shape), "force_shape": list(scans.force.shape),
        "units": scans.meta.get("units"), "sample_rate_hz": scans.meta.get("sample_rate_hz"),
        "sensor": {"name": sensor.get("name"), "taxels": sensor.get("taxels")},
        "normal_force": _stats(np.asarray(normal, np.float64).ravel()),
        "xy_extent_mm": [_stats(scans.pose[:, 0]), _stats(scans.pose[:, 1])] if scans.n_steps else None,
        "primitives": sorted(set(scans.traj_attrs["primitive"].tolist()) - {""}),
        "label_volumes": labels,
        "history": scans.meta.get("history", []) if full_history else history_summary(scans.meta.get("history", [])),
    }]
