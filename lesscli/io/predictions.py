"""Prediction files ``less.pred/1``: per scan class probabilities, labels, entropy, truth, geometry.

Every prediction is a volume (C, D, H, W); a 2D prediction is a volume of depth 1 whose geometry
places it at its slice (``meta['dim'] == 2``). Volumes may differ in shape between scans (e.g.
the ``large`` set), so arrays are stored flat with a shape table, like label volumes (the keys:
:data:`KEYS`). Files written before the optional keys existed tell a scan's prefixes by their order
(consecutive predictions of one insert and orientation with rising steps: :func:`scan_numbers`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError
from lesscli.io import checks
from lesscli.io.atomic import atomic_path
from lesscli.io.labels import INCLUSION, N_CLASSES, PILLAR, LabelVolume, check_codes
from lesscli.io.npfiles import read_npz, write_npz

# The format's keys, as docs/reference/formats.md prints them (tools/gen_reference.py).
KEYS = """\
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
scan_index         (S,) i64         optional: which scan of the imaged set each prediction
                                    images (the prefixes of ``--steps`` share one), rising
touch_count        (S,) i64         optional, with ``touch_xy_mm``: touches stored per prediction
touch_xy_mm        (sum, 2) f32     x, y (mm) of the pad's centre at the steps it saw in contact
=================  ===============  ==================================================
"""

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

    Without a threshold this is the argmax. With one, a voxel is pillar or inclusion exactly when that
    class's probability exceeds ``threshold`` (the larger of the two where both do); otherwise it takes the
    more likely of background and insert. At 0.5 and above this only demotes unsure voxels (the paper's
    hand-held rule, 0.8); below 0.5 it also labels voxels where the class is likely but not the most
    likely, the rule for a model that is right about where and unsure about how much. With
    ``min_volume_mm3`` > 0, inclusion regions (face-connected) smaller than that volume (voxels of
    ``spacing_mm``) take the more likely of background and insert too: an inclusion is a solid body, not
    a speck. With ``smooth_mm`` > 0 both rules read the probabilities :func:`smoothed` across each slice
    first, so that a boundary follows the neighbourhood rather than single pixels.
    """
    probs = smoothed(probs, smooth_mm, spacing_mm)
    tissue = probs[:2].argmax(axis=0).astype(np.uint8)
    return drop_specks(thresholded(probs, threshold, tissue), tissue, min_volume_mm3, spacing_mm)


def thresholded(probs: np.ndarray, threshold: float | None, tissue: np.ndarray) -> np.ndarray:
    """The threshold step of :func:`labels_from_probs`; ``tissue`` is the likelier of background and
    insert."""
    if threshold is None:
        return probs.argmax(axis=0).astype(np.uint8)
    thin = np.where(probs[INCLUSION] >= probs[PILLAR], INCLUSION, PILLAR).astype(np.uint8)
    return np.where(np.maximum(probs[PILLAR], probs[INCLUSION]) > threshold, thin, tissue).astype(np.uint8)


def drop_specks(labels: np.ndarray, tissue: np.ndarray, min_volume_mm3: float, spacing_mm) -> np.ndarray:
    """The region step of :func:`labels_from_probs`: inclusion regions under ``min_volume_mm3`` become
    ``tissue`` (a new array; ``labels`` is left as it is)."""
    if not min_volume_mm3 > 0:
        return labels
    from scipy import ndimage

    regions, n = ndimage.label(labels == INCLUSION)
    if not n:
        return labels
    voxels = np.bincount(regions.ravel(), minlength=n + 1)
    small = voxels * float(np.prod(spacing_mm)) < min_volume_mm3
    small[0] = False
    speck = small[regions]
    return np.where(speck, tissue, labels).astype(np.uint8)


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
        return {"threshold": self.threshold, "min_volume_mm3": self.min_volume_mm3,
                "smooth_mm": self.smooth_mm}


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
    scan: int = -1                        # the scan of the imaged set (-1: not recorded)
    # (T, 2) pad centres at the steps seen in contact; None: not recorded
    touch_xy_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.label is None:
            self.label = labels_from_probs(self.probs)
        if self.entropy is None:
            self.entropy = entropy(self.probs)

    def truth_volume(self) -> LabelVolume | None:
        return None if self.truth is None else LabelVolume(self.truth, self.origin_mm, self.spacing_mm,
                                                           self.insert)

    def label_volume(self) -> LabelVolume:
        return LabelVolume(self.label, self.origin_mm, self.spacing_mm, self.insert)

    def confidence(self) -> np.ndarray:
        """(D, H, W) float32 in [0, 1]: how far the most likely class stands above a uniform guess,
        (p_max - 1/C) / (1 - 1/C); 0 where nothing is known (every class equally likely), 1 where one
        class is certain."""
        p = np.asarray(self.probs, dtype=np.float32)
        c = p.shape[0]
        return np.clip((p.max(axis=0) - 1.0 / c) / (1.0 - 1.0 / c), 0.0, 1.0)


@dataclass
class PredictionSet:
    scans: list[ScanPrediction]
    meta: dict = field(default_factory=dict)


def scan_numbers(preds: list[ScanPrediction]) -> list[int]:
    """The scan (0, 1, ...) each prediction images: the recorded ``scan`` where every prediction has one,
    else by order (consecutive predictions of one insert and orientation with rising steps are prefixes
    of one scan, as ``image predict --steps`` writes them)."""
    if preds and all(p.scan >= 0 for p in preds):
        order = {s: k for k, s in enumerate(dict.fromkeys(p.scan for p in preds))}
        return [order[p.scan] for p in preds]
    out: list[int] = []
    for i, p in enumerate(preds):
        prev = preds[i - 1] if i else None
        same = (prev is not None and (prev.insert, prev.orientation) == (p.insert, p.orientation)
                and p.steps > prev.steps)
        out.append(out[-1] if same else (out[-1] + 1 if out else 0))
    return out


def whole_scans(preds: list[ScanPrediction]) -> list[int]:
    """Indices of the prediction of each scan's whole sequence (the one with the most steps; the last
    of its prefixes), in scan order."""
    best: dict[int, int] = {}
    for i, s in enumerate(scan_numbers(preds)):
        if s not in best or preds[i].steps >= preds[best[s]].steps:
            best[s] = i
    return [best[s] for s in sorted(best)]


def _flat(arrays: list[np.ndarray], dtype) -> np.ndarray:
    return np.concatenate([a.ravel() for a in arrays]).astype(dtype) if arrays else np.zeros(0, dtype)


def save_predictions(path: str, preds: PredictionSet) -> None:
    """Check (as :func:`load_predictions` does) and write atomically to ``path`` (``-`` = stdout)."""
    scans = preds.scans
    meta = {"schema": SCHEMA, "version": VERSION,
            **{k: v for k, v in preds.meta.items() if k not in ("schema", "version")}}
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
    if scans and all(p.scan >= 0 for p in scans):
        arrays["scan_index"] = np.array([p.scan for p in scans], np.int64)
    if scans and all(p.touch_xy_mm is not None for p in scans):
        touches = [np.asarray(p.touch_xy_mm, np.float32).reshape(-1, 2) for p in scans]
        arrays["touch_count"] = np.array([len(t) for t in touches], np.int64)
        arrays["touch_xy_mm"] = np.concatenate(touches).astype(np.float32)
    _checked_arrays(arrays, path)   # a writer never stores what its reader would refuse
    with atomic_path(path, ".npz") as tmp:
        write_npz(tmp, arrays)


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
    shapes = checks.numbers(checks.require(arrays, "probs_shape", name, WHAT), "probs_shape", name,
                            integer=True)
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
            raise DataError(f"{name}: '{key}' has {arr.size} values, 'probs_shape' and 'has_truth' need "
                            f"{size}")
        out[key] = arr
    _check_probs(out["probs_data"], shapes, name)
    for key in ("label_data", "truth_data"):
        check_codes(out[key], f"{name}: '{key}'")
    checks.finite(out["entropy_data"].reshape(-1, 1), "entropy_data", name, "value")
    if out["entropy_data"].size and out["entropy_data"].min() < 0:
        raise DataError(f"{name}: 'entropy_data' must be non-negative (nats)")
    out.update(_checked_optional(arrays, name, n))
    return out


def _checked_optional(arrays: dict, name: str, n: int) -> dict:
    """The optional keys (module docstring), when there: ``scan_index`` and ``touch_count`` /
    ``touch_xy_mm``."""
    out = {}
    if "scan_index" in arrays:
        index = checks.numbers(arrays["scan_index"], "scan_index", name, integer=True)
        checks.shape(index, "scan_index", name, (n,), f"({n},): one entry per prediction")
        if n and (index.min() < 0 or (np.diff(index) < 0).any()):
            raise DataError(f"{name}: 'scan_index' must count scans from 0 upwards, in order")
        out["scan_index"] = index
    if ("touch_count" in arrays) != ("touch_xy_mm" in arrays):
        have, lack = (("touch_count", "touch_xy_mm") if "touch_count" in arrays
                      else ("touch_xy_mm", "touch_count"))
        raise DataError(f"{name}: '{have}' without '{lack}'; the touches need both")
    if "touch_count" in arrays:
        count = checks.numbers(arrays["touch_count"], "touch_count", name, integer=True)
        checks.shape(count, "touch_count", name, (n,), f"({n},): one entry per prediction")
        if n and count.min() < 0:
            raise DataError(f"{name}: 'touch_count' must be >= 0 (touches per prediction), found "
                            f"{int(count.min())}")
        xy = checks.numbers(arrays["touch_xy_mm"], "touch_xy_mm", name)
        checks.shape(xy, "touch_xy_mm", name, (int(count.sum()), 2),
                     f"({int(count.sum())}, 2): 'touch_count' " "says how many x, y pairs")
        checks.finite(xy, "touch_xy_mm", name, "touch")
        out["touch_count"], out["touch_xy_mm"] = count, xy
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
    probs_off, vox_off = (np.concatenate([[0], np.cumsum(shapes.prod(axis=1))]),
                          np.concatenate([[0], np.cumsum(vox)]))
    truth_off = np.concatenate([[0], np.cumsum(np.where(a["has_truth"] > 0, vox, 0))])
    touch_off = np.concatenate([[0], np.cumsum(a["touch_count"])]) if "touch_count" in a else None
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
            entropy=a["entropy_data"][sl].reshape(shp[1:]).astype(np.float16),
            scan=int(a["scan_index"][i]) if "scan_index" in a else -1,
            touch_xy_mm=a["touch_xy_mm"][touch_off[i]:touch_off[i + 1]].astype(np.float32)
            if touch_off is not None else None))
    return PredictionSet(scans, meta)
