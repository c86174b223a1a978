"""Prediction files ``less.pred/1``: per scan class probabilities, labels, entropy, truth, geometry.

Every prediction is a volume (C, D, H, W); a 2D prediction is a volume of depth 1 whose geometry
places it at its slice (``meta['dim'] == 2``). Volumes may differ in shape between scans (e.g.
the ``large`` set), so arrays are stored flat with a shape table, like label volumes.

=================  ===============  ==================================================
key                shape            meaning
=================  ===============  ==================================================
probs_data         (sum,) f16       class probabilities, flattened per scan
probs_shape        (S, 4) i64       (C, D, H, W)
label_data         (sum,) u8        predicted codes (argmax, after the threshold rule)
entropy_data       (sum,) f16       Shannon entropy per voxel, nats
truth_data         (sum,) u8        true codes for scans with ``has_truth``
has_truth          (S,) bool
origin_mm          (S, 3) f64       z, y, x of voxel [0,0,0]
spacing_mm         (S, 3) f64
scan_insert        (S,) str
scan_orientation   (S,) i64
scan_steps         (S,) i64         number of input steps the prediction saw (prefix length)
meta               () str           JSON: schema, version, dim, threshold, model, seed, set, history
=================  ===============  ==================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError
from lesscli.io.atomic import atomic_path
from lesscli.io.labels import INCLUSION, PILLAR, LabelVolume
from lesscli.io.scans import read_npz

SCHEMA, VERSION = "less.pred", 1
EPS_LOG = 1e-12  # floor inside log(p) for the entropy of float16-rounded probabilities


def labels_from_probs(probs: np.ndarray, threshold: float | None = None, min_volume_mm3: float = 0.0,
                      spacing_mm=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Class codes from probabilities (C, ...) -> (...) uint8.

    Without a threshold this is the argmax. With one, a voxel is pillar or inclusion only when that
    class's probability exceeds ``threshold``; otherwise it takes the more likely of background and
    insert (the hand-held rule of the paper). With ``min_volume_mm3`` > 0, inclusion regions (face-
    connected) smaller than that volume (voxels of ``spacing_mm``) take the more likely of background
    and insert too: an inclusion is a solid body, not a speck.
    """
    probs = np.asarray(probs, dtype=np.float32)
    labels = probs.argmax(axis=0).astype(np.uint8)
    if threshold is not None:
        thin = np.isin(labels, (PILLAR, INCLUSION))
        weak = thin & (np.take_along_axis(probs, labels[None].astype(np.int64), 0)[0] <= threshold)
        labels[weak] = probs[:2].argmax(axis=0)[weak]
    if min_volume_mm3 > 0:
        from scipy import ndimage

        regions, n = ndimage.label(labels == INCLUSION)
        if n:
            voxels = np.bincount(regions.ravel(), minlength=n + 1)
            voxels[0] = 0
            small = voxels * float(np.prod(spacing_mm)) < min_volume_mm3
            small[0] = False
            speck = small[regions]
            labels[speck] = probs[:2].argmax(axis=0)[speck]
    return labels


def entropy(probs: np.ndarray) -> np.ndarray:
    """Shannon entropy in nats over axis 0, computed in float32; 0 * log 0 = 0."""
    p = np.asarray(probs, dtype=np.float32)
    return -(p * np.log(np.clip(p, EPS_LOG, None))).sum(axis=0)


@dataclass
class ScanPrediction:
    """One scan's prediction. Arrays are (C, D, H, W) / (D, H, W)."""

    probs: np.ndarray
    origin_mm: np.ndarray
    spacing_mm: np.ndarray
    truth: np.ndarray | None = None
    insert: str = ""
    orientation: int = 0
    steps: int = -1
    label: np.ndarray | None = None
    entropy: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.label is None:
            self.label = labels_from_probs(self.probs)
        if self.entropy is None:
            self.entropy = entropy(self.probs)

    def truth_volume(self) -> LabelVolume | None:
        return None if self.truth is None else LabelVolume(self.truth, self.origin_mm, self.spacing_mm, self.insert)

    def label_volume(self) -> LabelVolume:
        return LabelVolume(self.label, self.origin_mm, self.spacing_mm, self.insert)


@dataclass
class PredictionSet:
    scans: list[ScanPrediction]
    meta: dict = field(default_factory=dict)


def _flat(arrays: list[np.ndarray], dtype) -> np.ndarray:
    return np.concatenate([a.ravel() for a in arrays]).astype(dtype) if arrays else np.zeros(0, dtype)


def save_predictions(path: str, preds: PredictionSet) -> None:
    """Write atomically to ``path`` (``-`` = stdout)."""
    scans = preds.scans
    meta = {"schema": SCHEMA, "version": VERSION, **{k: v for k, v in preds.meta.items() if k not in ("schema", "version")}}
    arrays = {
        "probs_data": _flat([p.probs for p in scans], np.float16),
        "probs_shape": np.array([p.probs.shape for p in scans], np.int64).reshape(-1, 4),
        "label_data": _flat([p.label for p in scans], np.uint8),
        "entropy_data": _flat([p.entropy for p in scans], np.float16),
        "truth_data": _flat([p.truth for p in scans if p.truth is not None], np.uint8),
        "has_truth": np.array([p.truth is not None for p in scans], bool),
        "origin_mm": np.array([p.origin_mm for p in scans], np.float64).reshape(-1, 3),
        "spacing_mm": np.array([p.spacing_mm for p in scans], np.float64).reshape(-1, 3),
        "scan_insert": np.array([p.insert for p in scans], dtype=str),
        "scan_orientation": np.array([p.orientation for p in scans], np.int64),
        "scan_steps": np.array([p.steps for p in scans], np.int64),
        "meta": np.array(json.dumps(meta)),
    }
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, **arrays)


def load_predictions(path: str) -> PredictionSet:
    """Read and check a prediction file; problems raise DataError naming the file and key."""
    name = "<stdin>" if path == "-" else path
    arrays = read_npz(path, what="prediction file")
    try:
        meta = json.loads(str(arrays["meta"][()]))
    except (KeyError, json.JSONDecodeError):
        raise DataError(f"{name}: missing or unreadable 'meta' (not a {SCHEMA} file?)") from None
    if meta.get("schema") != SCHEMA or meta.get("version") != VERSION:
        raise DataError(f"{name}: schema {meta.get('schema')}/{meta.get('version')}, expected {SCHEMA}/{VERSION}")
    for key in ("probs_data", "probs_shape", "label_data", "entropy_data", "truth_data", "has_truth",
                "origin_mm", "spacing_mm", "scan_insert", "scan_orientation", "scan_steps"):
        if key not in arrays:
            raise DataError(f"{name}: missing key '{key}'")
    shapes = arrays["probs_shape"].reshape(-1, 4)
    vox = shapes[:, 1:].prod(axis=1)
    size = shapes.prod(axis=1)
    if arrays["probs_data"].size != size.sum() or arrays["label_data"].size != vox.sum():
        raise DataError(f"{name}: array sizes do not match 'probs_shape'")
    probs_off, vox_off = np.concatenate([[0], np.cumsum(size)]), np.concatenate([[0], np.cumsum(vox)])
    truth_off = np.concatenate([[0], np.cumsum(np.where(arrays["has_truth"], vox, 0))])
    if arrays["truth_data"].size != truth_off[-1]:
        raise DataError(f"{name}: 'truth_data' size does not match 'has_truth'")
    scans = []
    for i, shp in enumerate(shapes):
        sl = slice(vox_off[i], vox_off[i + 1])
        truth = arrays["truth_data"][truth_off[i]:truth_off[i + 1]].reshape(shp[1:]) if arrays["has_truth"][i] else None
        scans.append(ScanPrediction(
            probs=arrays["probs_data"][probs_off[i]:probs_off[i + 1]].reshape(shp),
            origin_mm=arrays["origin_mm"][i], spacing_mm=arrays["spacing_mm"][i], truth=truth,
            insert=str(arrays["scan_insert"][i]), orientation=int(arrays["scan_orientation"][i]),
            steps=int(arrays["scan_steps"][i]), label=arrays["label_data"][sl].reshape(shp[1:]),
            entropy=arrays["entropy_data"][sl].reshape(shp[1:])))
    return PredictionSet(scans, meta)
