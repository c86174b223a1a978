"""Summary records of the toolkit's files (``less info``): scan sets, prediction files, checkpoints, label
volumes and MRI scans, each told apart by its name, its content and its own schema."""

from __future__ import annotations

import os
import shlex

import numpy as np

from lesscli.data.compat import model_signature
from lesscli.errors import DataError
from lesscli.io.labels import CLASS_NAMES, LabelVolume, check_codes
from lesscli.io.scans import ScanSet


def _stats(values: np.ndarray) -> dict:
    if values.size == 0:
        return {"min": None, "mean": None, "max": None}
    return {"min": float(values.min()), "mean": float(values.mean()), "max": float(values.max())}


OUTPUT_FLAGS = ("-o", "--output")


def _is_joined_output(word: str) -> bool:
    """``--output=X``, ``-o=X`` or ``-oX``."""
    return word.startswith(("--output=", "-o=")) or (word.startswith("-o") and not word.startswith("--")
                                                     and len(word) > 2)


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
    per_scan = (np.bincount(scans.traj_scan, minlength=scans.n_scans) if scans.n_traj
                else np.zeros(scans.n_scans))
    normal = scans.force[..., 2] if scans.n_steps else np.zeros(0)
    return [{
        "kind": "scan set", "schema": f"{scans.meta.get('schema')}/{scans.meta.get('version')}",
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
        "history": scans.meta.get("history", []) if full_history
        else history_summary(scans.meta.get("history", [])),
    }]


def _class_voxels(volumes: list[np.ndarray]) -> dict:
    """Voxels of each class by name, over ``volumes`` of label codes (checked by their readers)."""
    counts = sum((np.bincount(v.ravel(), minlength=len(CLASS_NAMES)) for v in volumes),
                 np.zeros(len(CLASS_NAMES), np.int64))
    return {name: int(n) for name, n in zip(CLASS_NAMES, counts)}


ZYX = "z, y, x"                 # the axis order every grid record gives (the toolkit's D, H, W)


def describe_labels(volume: LabelVolume) -> list[dict]:
    """One record of a label volume: its grid (z, y, x, as every grid record), and each class's voxels
    and volume."""
    voxel_mm3 = float(np.prod(volume.spacing_mm))
    voxels = _class_voxels([volume.data])
    return [{"kind": "label volume", "axes": ZYX, "shape": list(volume.shape),
             "spacing_mm": volume.spacing_mm.tolist(), "origin_mm": volume.origin_mm.tolist(),
             "class_voxels": voxels, "class_volume_mm3": {k: n * voxel_mm3 for k, n in voxels.items()}}]


def world_axes(affine) -> list[int] | None:
    """For each array axis, the world axis (0 x, 1 y, 2 z) it runs along most (the largest direction
    cosine of its affine column); None where two array axes run along the same one (a very oblique grid)."""
    dominant = np.abs(np.asarray(affine, np.float64)[:3, :3]).argmax(axis=0)
    return [int(d) for d in dominant] if sorted(dominant.tolist()) == [0, 1, 2] else None


def describe_image(scan) -> list[dict]:
    """One record of an MRI scan (:class:`lesscli.mri.scan.MRIScan`, a NIfTI file or a DICOM folder that is
    not a label volume): its grid, given z, y, x as a label volume's is (``file_axes`` says which world
    axis each of the file's own axes runs along), and its intensities."""
    data = np.asarray(scan.data)
    finite = data[np.isfinite(data)] if data.dtype.kind == "f" else data.ravel()
    levels = np.percentile(finite, [0, 1, 50, 99, 100]).tolist() if finite.size else [None] * 5
    spacing = np.asarray(scan.spacing_mm, float)
    runs = world_axes(scan.affine) if data.ndim == 3 else None
    if runs is None:                       # not a 3D grid near the world axes: the file's own order
        axes, order, file_axes = "i, j, k (the file's order)", list(range(data.ndim)), None
    else:
        axes, order, file_axes = (ZYX, [runs.index(2), runs.index(1), runs.index(0)],
                                  ", ".join("xyz"[d] for d in runs))
    return [{"kind": "image volume", "format": scan.kind, "axes": axes, "file_axes": file_axes,
             "shape": [int(data.shape[i]) for i in order], "dtype": str(data.dtype),
             "spacing_mm": [float(spacing[i]) for i in order] if spacing.size == len(order)
             else spacing.tolist(),
             "intensity": dict(zip(("min", "p1", "median", "p99", "max"), levels)),
             "non_finite_voxels": int(data.size - finite.size)}]


def _holds_codes(data: np.ndarray) -> bool:
    """Label codes 0..3 only (:func:`lesscli.io.labels.check_codes`); an MRI scan has more levels, or
    fractions."""
    try:
        check_codes(data, "")
    except DataError:
        return False
    return data.size > 0


def describe_predictions(preds, full_history: bool = False) -> list[dict]:
    """One record of a prediction file (:class:`lesscli.io.predictions.PredictionSet`): what was imaged,
    on which grids, by which model, and what it labelled."""
    from lesscli.io.predictions import scan_numbers

    scans, meta = preds.scans, dict(preds.meta)
    history = meta.pop("history", [])
    return [{
        "kind": "prediction set", "schema": f"{meta.pop('schema', None)}/{meta.pop('version', None)}",
        "scans": len(set(scan_numbers(scans))), "images": len(scans),
        "with_truth": sum(p.truth is not None for p in scans),
        "inserts": sorted({p.insert for p in scans}), "orientations": sorted({p.orientation for p in scans}),
        "classes": sorted({int(p.probs.shape[0]) for p in scans}),
        "grid_shapes": sorted({tuple(int(n) for n in p.probs.shape[1:]) for p in scans}),
        "spacing_mm": sorted({tuple(float(v) for v in p.spacing_mm) for p in scans}),
        "steps": _stats(np.array([p.steps for p in scans], float)),
        "class_voxels": _class_voxels([p.label for p in scans]),
        "entropy_mean_nats": float(np.mean([p.entropy.astype(np.float64).mean() for p in scans])) if scans
        else None,
        "meta": meta, "history": history if full_history else history_summary(history),
    }]


def describe_checkpoint(ckpt: dict, full_history: bool = False) -> list[dict]:
    """One record of a checkpoint (:mod:`lesscli.io.checkpoint`): which model, how large, how it was
    trained, and on what grid it images."""
    config, extra = ckpt.get("config", {}), ckpt.get("extra", {})
    history = ckpt.get("history", [])
    epochs = [h for h in history if "epoch" in h]
    commands = [h for h in history if "command" in h]
    settings = None
    if config.get("model") == "forcemap":          # its fitted settings, without the per-depth prior tables
        kind, model = "classical imager", "forcemap"
        settings = {k: v for k, v in config.get("forcemap", {}).items() if not k.startswith("prior")}
    else:
        kind = "imager" if "image" in config else "representation"
        model = config.get("encoder", {}).get("name")
    norm, image = ckpt.get("norm_stats") or {}, config.get("image") or {}
    sig = model_signature(ckpt)
    return [{
        "kind": kind, "format": f"{ckpt.get('format')}/{ckpt.get('version')}", "model": model,
        "decoder": config.get("decoder", {}).get("name"),
        "parameters": int(sum(int(v.numel()) for v in ckpt.get("model_state", {}).values())),
        "epochs": len(epochs), "best_epoch": extra.get("best_epoch"), "best_loss": extra.get("best_loss"),
        "last_epoch": {k: v for k, v in epochs[-1].items() if k not in ("best", "step")} if epochs else None,
        "settings": settings, "grid": config.get("grid"),
        "labelling": {k: image[k] for k in ("threshold", "min_volume_mm3", "smooth_mm") if k in image}
        or None,
        "image": config.get("image"),
        "force_units": sig.get("force_units") or norm.get("force_units"), "pose_frame": sig.get("pose_frame"),
        "sensor": _sensor_line(sig), "training_steps": norm.get("n_steps"),
        "history": commands if full_history else history_summary(commands),
    }]


def _sensor_line(sig: dict) -> str | None:
    """``name (T taxels)`` of a checkpoint's sensor, None when it was not recorded."""
    taxels = sig.get("taxels")
    name = (sig.get("sensor") or {}).get("name")
    return None if taxels is None else f"{name or 'sensor'} ({taxels} taxels)"


def describe_file(path: str, full_history: bool = False, series: str | None = None) -> list[dict]:
    """The record of whatever toolkit file ``path`` is: a checkpoint (``.pt``); a NIfTI file (``.nii``,
    ``.nii.gz``), a label volume where it holds label codes only, else an MRI scan, as a DICOM folder is;
    a folder of scan-set shards; else a ``.npz`` (``-``: stdin) read once and described as the prediction
    file or scan set its schema names. ``series``: the series of a DICOM folder holding several."""
    from lesscli.io import predictions, scans
    from lesscli.io.checkpoint import load_checkpoint
    from lesscli.io.checks import declared_schema
    from lesscli.io.labels import labels_from_nifti
    from lesscli.io.npfiles import read_npz
    from lesscli.mri.scan import load_scan

    if series is not None and not os.path.isdir(path):
        load_scan(path, series=series)          # a file holds one scan: DataError naming the file
    low = path.lower()
    if low.endswith((".pt", ".pth")):
        return describe_checkpoint(load_checkpoint(path), full_history)
    if low.endswith((".nii", ".nii.gz")) or (os.path.isdir(path) and not any(
            f.endswith(".npz") for f in os.listdir(path))):      # a NIfTI file, or a DICOM folder
        image = load_scan(path, series=series)          # read once: a label volume, or an MRI scan
        if image.kind == "nifti" and _holds_codes(np.asarray(image.data)):
            return describe_labels(labels_from_nifti(np.asarray(image.data), image.affine, path))
        return describe_image(image)
    if path != "-" and os.path.isdir(path):
        return describe(scans.load_scans(path), path, full_history)
    name = "<stdin>" if path == "-" else path
    arrays = read_npz(path, f"{scans.WHAT} or {predictions.WHAT}")
    if declared_schema(arrays) == predictions.SCHEMA:
        return describe_predictions(predictions.from_arrays(arrays, name), full_history)
    return describe(scans.validate(arrays, name), path, full_history)
