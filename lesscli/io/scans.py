"""The scan-set format ``less.scans/1``: one reader, one writer, one validator.

A scan set is a ``.npz`` (loaded with ``allow_pickle=False``) holding ragged trajectories as flat
arrays plus offsets:

=====================  ===========  =========================================================
key                    shape        meaning
=====================  ===========  =========================================================
pose                   (N, 6) f32   x, y, z mm, roll, pitch, yaw rad of the pad, phantom frame
force                  (N, T, 3) f32 per-taxel force (newtons, or sensor counts: meta units)
time_s                 (N,) f64     time since the trajectory's first step, s
traj_offsets           (R+1,) i64   steps of trajectory r are [offsets[r], offsets[r+1])
traj_scan              (R,) i64     scan index of each trajectory (non-decreasing)
traj_<attr>            (R,)         per-trajectory attributes (TRAJ_ATTRS), NaN/'' = unknown
scan_insert            (S,) str     insert name (e.g. St12C13)
scan_orientation       (S,) i64     insert rotation, multiples of 45 degrees (0..7)
scan_label             (S,) i64     index into the label volumes, -1 when none
label_data             (sum,) u8    label volumes, flattened and concatenated
label_shape            (L, 3) i64   (D, H, W) of each volume
label_origin_mm        (L, 3) f64   z, y, x of voxel [0,0,0] (see lesscli.io.labels)
label_spacing_mm       (L, 3) f64   dz, dy, dx
label_name             (L,) str
meta                   () str       JSON: schema, version, units, sensor, sample_rate_hz, history
=====================  ===========  =========================================================

A scan's trajectories are contiguous, so scan s covers one contiguous range of steps: the model
sees a scan as its trajectories concatenated in time.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
import time
import zipfile
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from lesscli import __version__
from lesscli.errors import DataError
from lesscli.io.atomic import atomic_path, open_input_bytes
from lesscli.io.labels import LabelVolume, check_codes

SCHEMA, VERSION = "less.scans", 1
TRAJ_ATTRS = {"target_force_n": np.float32, "yaw_rad": np.float32, "dx_mm": np.float32,
              "dy_mm": np.float32, "primitive": str}
POSE_UNITS = ["mm", "mm", "mm", "rad", "rad", "rad"]


def default_meta(sensor: dict, force_units: str = "N", sample_rate_hz: float = 100.0, **extra) -> dict:
    """A fresh ``meta`` dict for a new scan set."""
    meta = {"schema": SCHEMA, "version": VERSION,
            "units": {"pose": POSE_UNITS, "force": force_units, "time": "s", "length": "mm"},
            "sensor": sensor, "sample_rate_hz": float(sample_rate_hz), "history": []}
    meta.update(extra)
    return meta


def append_history(meta: dict, seed: int | None = None, argv: list[str] | None = None, **info) -> dict:
    """Return a copy of ``meta`` with one more ``history`` entry (command line, version, seed, time)."""
    entry = {"command": shlex.join(["less", *(sys.argv[1:] if argv is None else argv)]),
             "version": __version__, "seed": seed, "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **info}
    return {**meta, "history": [*meta.get("history", []), entry]}


@dataclass
class ScanSet:
    """An in-memory scan set (see the module docstring for shapes and units)."""

    pose: np.ndarray
    force: np.ndarray
    time_s: np.ndarray
    traj_offsets: np.ndarray
    traj_scan: np.ndarray
    scan_insert: np.ndarray
    scan_orientation: np.ndarray
    scan_label: np.ndarray
    labels: list[LabelVolume] = field(default_factory=list)
    traj_attrs: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, kind in TRAJ_ATTRS.items():
            if key not in self.traj_attrs:
                self.traj_attrs[key] = np.full(self.traj_scan.shape, "" if kind is str else np.nan).astype(kind)

    @property
    def n_steps(self) -> int:
        return int(self.pose.shape[0])

    @property
    def n_traj(self) -> int:
        return int(self.traj_scan.shape[0])

    @property
    def n_scans(self) -> int:
        return int(self.scan_insert.shape[0])

    @property
    def n_taxels(self) -> int:
        return int(self.force.shape[1])

    def traj_lengths(self) -> np.ndarray:
        return np.diff(self.traj_offsets)

    def scan_traj_offsets(self) -> np.ndarray:
        """(S+1,) trajectories of scan s are [o[s], o[s+1])."""
        return np.searchsorted(self.traj_scan, np.arange(self.n_scans + 1), side="left").astype(np.int64)

    def scan_step_offsets(self) -> np.ndarray:
        """(S+1,) steps of scan s are [o[s], o[s+1])."""
        return self.traj_offsets[self.scan_traj_offsets()]

    def scan_steps(self, s: int) -> slice:
        o = self.scan_step_offsets()
        return slice(int(o[s]), int(o[s + 1]))

    def label_of(self, s: int) -> LabelVolume | None:
        idx = int(self.scan_label[s])
        return None if idx < 0 else self.labels[idx]

    def select_steps(self, keep: np.ndarray) -> ScanSet:
        """Keep the steps where ``keep`` (N,) is True; trajectories left empty are dropped."""
        keep = np.asarray(keep, dtype=bool)
        traj_of_step = np.repeat(np.arange(self.n_traj), self.traj_lengths())
        counts = np.bincount(traj_of_step[keep], minlength=self.n_traj).astype(np.int64)
        sub = replace(self, pose=self.pose[keep], force=self.force[keep], time_s=self.time_s[keep],
                      traj_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))
        return sub.select_trajectories(counts > 0)

    def select_trajectories(self, keep: np.ndarray) -> ScanSet:
        """Keep the trajectories where ``keep`` (R,) is True (scans keep their place, maybe empty)."""
        keep = np.asarray(keep, dtype=bool)
        step_keep = np.repeat(keep, self.traj_lengths())
        lengths = self.traj_lengths()[keep]
        return replace(self, pose=self.pose[step_keep], force=self.force[step_keep],
                       time_s=self.time_s[step_keep],
                       traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                       traj_scan=self.traj_scan[keep],
                       traj_attrs={k: v[keep] for k, v in self.traj_attrs.items()})

    def select_scans(self, scans: np.ndarray) -> ScanSet:
        """Keep the given scan indices (in the given order); unused label volumes are dropped."""
        scans = np.asarray(scans, dtype=np.int64)
        toff = self.scan_traj_offsets()
        trajs = np.concatenate([np.arange(toff[s], toff[s + 1]) for s in scans]) if len(scans) else np.zeros(0, np.int64)
        lengths = self.traj_lengths()[trajs]
        steps = np.concatenate([np.arange(self.traj_offsets[t], self.traj_offsets[t + 1]) for t in trajs]) \
            if len(trajs) else np.zeros(0, np.int64)
        new_scan_of_traj = np.repeat(np.arange(len(scans)), toff[scans + 1] - toff[scans])
        used = sorted({int(i) for i in self.scan_label[scans] if i >= 0})
        remap = {old: new for new, old in enumerate(used)}
        return replace(self, pose=self.pose[steps], force=self.force[steps], time_s=self.time_s[steps],
                       traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                       traj_scan=new_scan_of_traj.astype(np.int64),
                       traj_attrs={k: v[trajs] for k, v in self.traj_attrs.items()},
                       scan_insert=self.scan_insert[scans], scan_orientation=self.scan_orientation[scans],
                       scan_label=np.array([remap.get(int(i), -1) for i in self.scan_label[scans]], np.int64),
                       labels=[self.labels[i] for i in used])


# ---------------------------------------------------------------------------------------------- validation

def _require(arrays: dict, key: str, name: str) -> np.ndarray:
    if key not in arrays:
        raise DataError(f"{name}: missing key '{key}' (not a {SCHEMA}/{VERSION} scan set?)")
    return arrays[key]


def _check_shape(arr: np.ndarray, key: str, name: str, ndim: int, expected: str, tail: tuple = ()) -> None:
    if arr.ndim != ndim or (tail and tuple(arr.shape[ndim - len(tail):]) != tail):
        raise DataError(f"{name}: '{key}' has shape {arr.shape}, expected {expected}")


def _check_finite(arr: np.ndarray, key: str, name: str) -> None:
    bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1) if arr.size else np.zeros(0, bool)
    if bad.any():
        raise DataError(f"{name}: '{key}' has NaN or inf at step {int(np.flatnonzero(bad)[0])} "
                        f"({int(bad.sum())} steps affected)")


def parse_meta(arrays: dict, name: str) -> dict:
    raw = _require(arrays, "meta", name)
    try:
        meta = json.loads(str(raw[()]))
    except (json.JSONDecodeError, TypeError, ValueError):
        raise DataError(f"{name}: 'meta' is not a JSON string") from None
    if meta.get("schema") != SCHEMA:
        raise DataError(f"{name}: schema is '{meta.get('schema')}', expected '{SCHEMA}'")
    if meta.get("version") != VERSION:
        raise DataError(f"{name}: unsupported {SCHEMA} version {meta.get('version')!r} "
                        f"(this toolkit reads version {VERSION})")
    return meta


def _labels_from(arrays: dict, name: str) -> list[LabelVolume]:
    shapes = np.asarray(_require(arrays, "label_shape", name), dtype=np.int64).reshape(-1, 3)
    data = _require(arrays, "label_data", name)
    sizes = shapes.prod(axis=1)
    if data.ndim != 1 or data.shape[0] != sizes.sum():
        raise DataError(f"{name}: 'label_data' has {data.size} values, 'label_shape' needs {int(sizes.sum())}")
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    origin = np.asarray(_require(arrays, "label_origin_mm", name), np.float64).reshape(-1, 3)
    spacing = np.asarray(_require(arrays, "label_spacing_mm", name), np.float64).reshape(-1, 3)
    names = arrays.get("label_name", np.array([""] * len(shapes)))
    if not (len(origin) == len(spacing) == len(shapes) == len(names)):
        raise DataError(f"{name}: label geometry arrays disagree in length")
    if len(spacing) and not (np.isfinite(spacing).all() and (spacing > 0).all() and np.isfinite(origin).all()):
        raise DataError(f"{name}: 'label_spacing_mm' must be positive and finite")
    check_codes(data, f"{name}: 'label_data'")
    return [LabelVolume(data[offsets[i]:offsets[i + 1]].reshape(shapes[i]), origin[i], spacing[i], str(names[i]))
            for i in range(len(shapes))]


def validate(arrays: dict, name: str) -> ScanSet:
    """Check every key, shape, dtype and value; return the ScanSet or raise DataError naming the problem."""
    meta = parse_meta(arrays, name)
    pose, force = _require(arrays, "pose", name), _require(arrays, "force", name)
    _check_shape(pose, "pose", name, 2, "(N, 6)", (6,))
    _check_shape(force, "force", name, 3, "(N, T, 3)", (3,))
    n = pose.shape[0]
    if force.shape[0] != n:
        raise DataError(f"{name}: 'force' has {force.shape[0]} steps but 'pose' has {n}")
    taxels = (meta.get("sensor") or {}).get("taxels")
    if taxels is not None and force.shape[1] != taxels:
        raise DataError(f"{name}: 'force' has {force.shape[1]} taxels, meta sensor says {taxels}")
    _check_finite(pose, "pose", name)
    _check_finite(force, "force", name)
    time_s = np.asarray(arrays.get("time_s", np.zeros(n)), np.float64)
    _check_shape(time_s, "time_s", name, 1, f"({n},)")
    offsets = np.asarray(_require(arrays, "traj_offsets", name), np.int64)
    if offsets.ndim != 1 or offsets.size < 1 or offsets[0] != 0 or offsets[-1] != n or np.any(np.diff(offsets) < 0):
        raise DataError(f"{name}: 'traj_offsets' must rise from 0 to the step count {n}")
    traj_scan = np.asarray(_require(arrays, "traj_scan", name), np.int64)
    scan_insert = np.asarray(_require(arrays, "scan_insert", name)).astype(str)
    n_scans = scan_insert.shape[0]
    if traj_scan.shape != (offsets.size - 1,):
        raise DataError(f"{name}: 'traj_scan' has shape {traj_scan.shape}, expected ({offsets.size - 1},)")
    if traj_scan.size and (np.any(np.diff(traj_scan) < 0) or traj_scan[0] < 0 or traj_scan[-1] >= n_scans):
        raise DataError(f"{name}: 'traj_scan' must be non-decreasing scan indices in 0..{n_scans - 1}")
    orient = np.asarray(arrays.get("scan_orientation", np.zeros(n_scans)), np.int64)
    scan_label = np.asarray(arrays.get("scan_label", -np.ones(n_scans)), np.int64)
    labels = _labels_from(arrays, name) if "label_shape" in arrays else []
    if orient.shape != (n_scans,) or scan_label.shape != (n_scans,):
        raise DataError(f"{name}: 'scan_orientation'/'scan_label' must have one entry per scan ({n_scans})")
    if np.any(scan_label >= len(labels)) or np.any(scan_label < -1):
        raise DataError(f"{name}: 'scan_label' points past the {len(labels)} label volumes")
    attrs = {}
    for key, kind in TRAJ_ATTRS.items():
        arr = arrays.get(f"traj_{key}")
        if arr is None:
            arr = np.full(traj_scan.shape, "" if kind is str else np.nan, dtype=object if kind is str else kind)
        arr = np.asarray(arr).astype(kind)
        if arr.shape != traj_scan.shape:
            raise DataError(f"{name}: 'traj_{key}' has shape {arr.shape}, expected {traj_scan.shape}")
        attrs[key] = arr
    return ScanSet(pose.astype(np.float32), force.astype(np.float32), time_s, offsets, traj_scan, scan_insert,
                   orient, scan_label, labels, attrs, meta)


# ---------------------------------------------------------------------------------------------- read / write

def read_npz(path: str, what: str = "scan set") -> dict[str, np.ndarray]:
    """All arrays of a ``.npz`` without pickle; corrupt, truncated or pickled files raise DataError."""
    name = "<stdin>" if path == "-" else path
    src = open_input_bytes(path)
    try:
        with np.load(src, allow_pickle=False) as npz:
            arrays = {}
            for key in npz.files:
                try:
                    arrays[key] = npz[key]
                except ValueError as exc:
                    if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
                        raise DataError(f"{name}: key '{key}' holds a pickled Python object; a {what} "
                                        "must hold plain arrays (refusing to unpickle)") from None
                    raise
    except DataError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError) as exc:
        raise DataError(f"{name}: not a readable .npz {what} (truncated or corrupt: {exc})") from None
    return arrays


def load_scans(path: str) -> ScanSet:
    """Read and validate a scan set: a ``.npz`` file, ``-`` (stdin), or a directory of ``.npz`` shards."""
    if path != "-" and os.path.isdir(path):
        shards = sorted(f for f in os.listdir(path) if f.endswith(".npz"))
        if not shards:
            raise DataError(f"{path}: directory holds no .npz shards")
        return concat([load_scans(os.path.join(path, f)) for f in shards], names=shards)
    return validate(read_npz(path), "<stdin>" if path == "-" else path)


def to_arrays(scans: ScanSet) -> dict[str, np.ndarray]:
    """The ``.npz`` arrays of ``scans`` (inverse of ``validate``)."""
    labels = scans.labels
    arrays = {
        "pose": scans.pose.astype(np.float32), "force": scans.force.astype(np.float32),
        "time_s": scans.time_s.astype(np.float64), "traj_offsets": scans.traj_offsets.astype(np.int64),
        "traj_scan": scans.traj_scan.astype(np.int64), "scan_insert": scans.scan_insert.astype(str),
        "scan_orientation": scans.scan_orientation.astype(np.int64), "scan_label": scans.scan_label.astype(np.int64),
        "label_data": np.concatenate([v.data.ravel() for v in labels]) if labels else np.zeros(0, np.uint8),
        "label_shape": np.array([v.shape for v in labels], np.int64).reshape(-1, 3),
        "label_origin_mm": np.array([v.origin_mm for v in labels], np.float64).reshape(-1, 3),
        "label_spacing_mm": np.array([v.spacing_mm for v in labels], np.float64).reshape(-1, 3),
        "label_name": np.array([v.name for v in labels], dtype=str),
        "meta": np.array(json.dumps(scans.meta)),
    }
    for key, kind in TRAJ_ATTRS.items():
        default = np.full(scans.n_traj, "" if kind is str else np.nan)
        arrays[f"traj_{key}"] = np.asarray(scans.traj_attrs.get(key, default)).astype(kind)
    return arrays


def save_scans(path: str, scans: ScanSet, compress: bool = True) -> None:
    """Validate and write ``scans`` atomically to ``path`` (``-`` = stdout)."""
    arrays = to_arrays(scans)
    validate(arrays, path)
    with atomic_path(path, ".npz") as tmp:
        (np.savez_compressed if compress else np.savez)(tmp, **arrays)


def concat(parts: list[ScanSet], names: list[str] | None = None) -> ScanSet:
    """Concatenate scan sets whose sensor and units agree; identical label volumes are stored once.

    Sample rates may differ (the paper trains on pokes subsampled 1:50 together with primitives
    subsampled 1:10): the result then has ``sample_rate_hz`` None, and each step's ``time_s`` is the
    authority on timing.
    """
    if not parts:
        raise DataError("nothing to concatenate")
    names = names or [f"input {i + 1}" for i in range(len(parts))]
    first = parts[0].meta
    for part, name in zip(parts[1:], names[1:]):
        for key in ("sensor", "units"):
            if part.meta.get(key) != first.get(key):
                raise DataError(f"{name}: '{key}' differs from {names[0]}; cannot concatenate "
                                f"({part.meta.get(key)} vs {first.get(key)})")
    labels: list[LabelVolume] = []
    index: dict[str, int] = {}
    scan_label, traj_offsets, traj_scan = [], [np.zeros(1, np.int64)], []
    steps = scans_before = 0
    for part in parts:
        remap = []
        for vol in part.labels:
            key = vol.content_hash()
            if key not in index:
                index[key] = len(labels)
                labels.append(vol)
            remap.append(index[key])
        scan_label.append(np.array([remap[i] if i >= 0 else -1 for i in part.scan_label], np.int64))
        traj_offsets.append(part.traj_offsets[1:] + steps)
        traj_scan.append(part.traj_scan + scans_before)
        steps += part.n_steps
        scans_before += part.n_scans
    history = [h for p in parts for h in p.meta.get("history", [])]

    def cat(attr: str) -> np.ndarray:
        return np.concatenate([getattr(p, attr) for p in parts])

    return ScanSet(cat("pose"), cat("force"), cat("time_s"), np.concatenate(traj_offsets), np.concatenate(traj_scan),
                   cat("scan_insert"), cat("scan_orientation"), np.concatenate(scan_label), labels,
                   {k: np.concatenate([p.traj_attrs[k] for p in parts]) for k in TRAJ_ATTRS},
                   {**first, "history": history, "sample_rate_hz": _common_rate(parts)})


def _common_rate(parts: list[ScanSet]) -> float | None:
    """The parts' ``sample_rate_hz`` when they all agree, else None (mixed rates)."""
    rates = {p.meta.get("sample_rate_hz") for p in parts}
    return rates.pop() if len(rates) == 1 else None
