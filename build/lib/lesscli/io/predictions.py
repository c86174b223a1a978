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
meta               () str           JSON: schema, version, dim, labelling rule (threshold,
                                    min_volume_mm3, smooth_mm), model, seed, set, history
=================  ===============  ==================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError
from lesscli.io import checks
from lesscli.io.atomic import atomic_path
from lesscli.io.labels import INCLUSION, N_CLASSES, PILLAR, LabelVolume, check_codes
from lesscli.io.npfiles import read_npz

SCHEMA, VERSION = "less.pred", 1
EPS_LOG = 1e-12  # floor inside log(p) for the entropy of float16-rounded probabilities


def smoothed(probs: np.ndarray, smooth_mm: float, spacing_mm) -> np.ndarray:
    """Class probabilities (C, ..., H, W) averaged over a Gaussian of standard deviation ``smooth_mm``
    across each slice (the last two axes, pixels of ``spacing_mm``; slices are not mixed: the label
    grids' slices are thicker than their pixels), float32; still a distribution per voxel. 0: as given."""
    probs = np.asarray(probs, dtype=np.float32)
    if smooth_mm <= 0:
        return probs
    from scipy import ndimage

    dy, dx = (float(v) for v in np.asarray(spacing_mm, np.float64)[-2:])
    sigma = (0.0,) * (probs.ndim - 2) + (smooth_mm / dy, smooth_mm / dx)
    return ndimage.gaussian_filter(probs, sigma, mode="nearest")


def labels_from_probs(probs: np.ndarray, threshold: float | None = None, min_volume_mm3: float = 0.0,
                      spacing_mm=(1.0, 1.0, 1.0), smooth_mm: float = 0.0) -> np.ndarray:
    """Class codes from probabilities (C, ...) -> (...) uint8.

    Without a threshold this is the argmax. With one, a voxel is pillar or inclusion only when that
    class's probability exceeds ``threshold``; otherwise it takes the more likely of background and
    insert (the hand-held rule of the paper). With ``min_volume_mm3`` > 0, inclusion regions (face-
    connected) smaller than that volume (voxels of ``spacing_mm``) take the more likely of background
    and insert too: an inclusion is a solid body, not a speck. With ``smooth_mm`` > 0 both rules read
    the probabilities :func:`smoothed` across each slice first, so that a boundary follows the
    neighbourhood rather than single pixels.
    """
    probs = smoothed(probs, smooth_mm, spacing_mm)
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


@dataclass(frozen=True)
class Labelling:
    """A labelling rule: the settings of :func:`labels_from_probs` beside the probabilities. ``image
    fit --val`` chooses one and stores it in the model (``config['image']``); ``image predict``,
    ``stream`` and ``guide`` apply it (see ``lesscli.infer.predict.labelling_rule``)."""

    threshold: float | None = None
    min_volume_mm3: float = 0.0
    smooth_mm: float = 0.0

    def labels(self, probs: np.ndarray, spacing_mm) -> np.ndarray:
        return labels_from_probs(probs, self.threshold, self.min_volume_mm3, spacing_mm, self.smooth_mm)

    def to_dict(self) -> dict:
        return {"threshold": self.threshold, "min_volume_mm3": self.min_volume_mm3, "smooth_mm": self.smooth_mm}


def nothing_known(shape: tuple[int, ...]) -> np.ndarray:
    """The image of a scan without touches: uniform class probabilities (C, ...) float32, so maximum
    entropy ln C everywhere. Every predictor (learned, force map, streaming) applies this one rule."""
    return np.full(shape, 1.0 / shape[0], np.float32)


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
    """Check (as :func:`load_predictions` does) and write atomically to ``path`` (``-`` = stdout)."""
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
    _checked_arrays(arrays, path)   # a writer never stores what its reader would refuse
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, **arrays)


WHAT = f"{SCHEMA}/{VERSION} prediction file"
PROB_SUM_TOL = 0.02  # |sum of class probabilities - 1| allowed after float16 storage


def _check_probs(probs: np.ndarray, shapes: np.ndarray, name: str) -> None:
    """Class probabilities: finite, in [0, 1], summing to 1 over the classes of every voxel."""
    checks.finite(probs.reshape(-1, 1), "probs_data", name, "value")
    if probs.size and (probs.min() < 0 or probs.max() > 1):
        raise DataError(f"{name}: 'probs_data' must be probabilities in 0..1, found {float(probs.min()):g}.."
                        f"{float(probs.max()):g}")
    offset = 0
    for i, shp in enumerate(shapes):
        size = int(np.prod(shp))
        total = probs[offset:offset + size].reshape(shp).astype(np.float32).sum(axis=0)
        offset += size
        if total.size and np.abs(total - 1).max() > PROB_SUM_TOL:
            raise DataError(f"{name}: 'probs_data' of scan {i} does not sum to 1 over the classes "
                            f"(found {float(total.min()):.3g}..{float(total.max()):.3g})")


def _checked_arrays(arrays: dict, name: str) -> dict:
    """Every key of a prediction file, type-, shape- and value-checked (see the module docstring)."""
    shapes = checks.numbers(checks.require(arrays, "probs_shape", name, WHAT), "probs_shape", name, integer=True)
    checks.shape(shapes, "probs_shape", name, (None, 4), "(S, 4): C, D, H, W of each scan")
    if shapes.size and (shapes.min() < 1 or (shapes[:, 0] != N_CLASSES).any()):
        raise DataError(f"{name}: 'probs_shape' must give {N_CLASSES} classes and at least 1 voxel per axis")
    n = len(shapes)
    out = {"probs_shape": shapes}
    for key in ("has_truth", "scan_orientation", "scan_steps", "scan_insert", "origin_mm", "spacing_mm"):
        arr = checks.require(arrays, key, name, WHAT)
        arr = checks.text_array(arr, key, name, "insert names") if key == "scan_insert" else \
            checks.numbers(arr, key, name, integer=key != "origin_mm" and key != "spacing_mm")
        checks.shape(arr, key, name, (n, 3) if key.endswith("_mm") else (n,),
                     f"({n}, 3)" if key.endswith("_mm") else f"({n},): one entry per scan")
        out[key] = arr
    checks.in_range(out["has_truth"], "has_truth", name, 0, 1, " (true/false)")
    checks.finite(out["origin_mm"], "origin_mm", name, "scan")
    checks.positive(out["spacing_mm"], "spacing_mm", name, "scan")
    vox = shapes[:, 1:].prod(axis=1)
    sizes = {"probs_data": int(shapes.prod(axis=1).sum()), "label_data": int(vox.sum()),
             "entropy_data": int(vox.sum()), "truth_data": int((vox * out["has_truth"]).sum())}
    for key, size in sizes.items():
        arr = checks.numbers(checks.require(arrays, key, name, WHAT), key, name)
        if arr.ndim != 1 or arr.size != size:
            raise DataError(f"{name}: '{key}' has {arr.size} values, 'probs_shape' and 'has_truth' need {size}")
        out[key] = arr
    _check_probs(out["probs_data"], shapes, name)
    for key in ("label_data", "truth_data"):
        check_codes(out[key], f"{name}: '{key}'")
    checks.finite(out["entropy_data"].reshape(-1, 1), "entropy_data", name, "value")
    if out["entropy_data"].size and out["entropy_data"].min() < 0:
        raise DataError(f"{name}: 'entropy_data' must be non-negative (nats)")
    return out


def load_predictions(path: str) -> PredictionSet:
    """Read and check a prediction file; problems raise DataError naming the file and key."""
    return from_arrays(read_npz(path, what=WHAT), "<stdin>" if path == "-" else path)


def from_arrays(arrays: dict, name: str) -> PredictionSet:
    """The prediction set of a file's ``arrays`` (checked; DataError names ``name`` and the key)."""
    meta = checks.schema_meta(arrays, name, SCHEMA, VERSION, "prediction file")
    a = _checked_arrays(arrays, name)
    shapes = a["probs_shape"]
    vox = shapes[:, 1:].prod(axis=1)
    probs_off, vox_off = np.concatenate([[0], np.cumsum(shapes.prod(axis=1))]), np.concatenate([[0], np.cumsum(vox)])
    truth_off = np.concatenate([[0], np.cumsum(np.where(a["has_truth"] > 0, vox, 0))])
    scans = []
    for i, shp in enumerate(shapes):
        sl = slice(vox_off[i], vox_off[i + 1])
        truth = a["truth_data"][truth_off[i]:truth_off[i + 1]].reshape(shp[1:]).astype(np.uint8) \
            if a["has_truth"][i] else None
        scans.append(ScanPrediction(
            probs=a["probs_data"][probs_off[i]:probs_off[i + 1]].reshape(shp).astype(np.float16),
            origin_mm=a["origin_mm"][i], spacing_mm=a["spacing_mm"][i], truth=truth,
            insert=str(a["scan_insert"][i]), orientation=int(a["scan_orientation"][i]),
            steps=int(a["scan_steps"][i]), label=a["label_data"][sl].reshape(shp[1:]).astype(np.uint8),
            entropy=a["entropy_data"][sl].reshape(shp[1:]).astype(np.float16)))
    return PredictionSet(scans, meta)
