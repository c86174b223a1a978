"""Summary records of a scan set (``less info``)."""

from __future__ import annotations

import numpy as np

from lesscli.io.scans import ScanSet


def _stats(values: np.ndarray) -> dict:
    if values.size == 0:
        return {"min": None, "mean": None, "max": None}
    return {"min": float(values.min()), "mean": float(values.mean()), "max": float(values.max())}


def describe(scans: ScanSet, path: str) -> list[dict]:
    """One record describing ``scans`` (file name kept out when reading stdin, so pipes compare equal)."""
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
        "history": scans.meta.get("history", []),
    }]
