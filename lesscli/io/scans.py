"""The scan-set format ``less.scans/1``: one reader, one writer, one validator.

A scan set is a ``.npz`` (loaded with ``allow_pickle=False``) holding ragged trajectories as flat
arrays plus offsets (the keys: :data:`KEYS`). A scan's trajectories are contiguous, so scan s covers
one contiguous range of steps: the model sees a scan as its trajectories concatenated in time.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shlex
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from lesscli import __version__
from lesscli.errors import DataError
from lesscli.io import checks
from lesscli.io.atomic import atomic_path
from lesscli.io.labels import LabelVolume, check_codes
from lesscli.io.npfiles import read_npz, write_npz

# The format's keys, as docs/reference/formats.md prints them (tools/gen_reference.py).
KEYS = """\
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
"""

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


def recorded_time() -> str:
    """The time a history entry records: now, or ``SOURCE_DATE_EPOCH`` (seconds since 1970, UTC; the
    reproducible-builds convention) when set, so that reruns can write the same bytes."""
    text = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if text:
        try:
            return time.strftime("%Y-%m-%dT%H:%M:%S+0000", time.gmtime(int(text)))
        except (ValueError, OverflowError, OSError):
            logging.getLogger("less").warning("SOURCE_DATE_EPOCH=%r is not a whole number of seconds; "
                                              "the history records the time now", text)
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def append_history(meta: dict, seed: int | None = None, argv: list[str] | None = None, **info) -> dict:
    """Return a copy of ``meta`` with one more ``history`` entry (command line, version, seed, time:
    :func:`recorded_time`)."""
    entry = {"command": shlex.join(["less", *(sys.argv[1:] if argv is None else argv)]),
             "version": __version__, "seed": seed, "time": recorded_time(), **info}
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
                self.traj_attrs[key] = np.full(self.traj_scan.shape,
                                               "" if kind is str else np.nan).astype(kind)

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

    def touched_scans(self) -> np.ndarray:
        """Indices of the scans with at least one step (an untouched scan has none)."""
        return np.flatnonzero(np.diff(self.scan_step_offsets()) > 0)

    def fingerprint(self) -> str:
        """Content hash of the steps, trajectories, scans and label volumes (meta and history excluded)."""
        h = hashlib.sha1()
        for arr in (self.pose, self.force, self.time_s, self.traj_offsets, self.traj_scan, self.scan_insert,
                    self.scan_orientation, self.scan_label):
            h.update(np.ascontiguousarray(arr).tobytes())
        for vol in self.labels:
            h.update(vol.content_hash().encode())
        return h.hexdigest()

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
        trajs = (np.concatenate([np.arange(toff[s], toff[s + 1]) for s in scans]) if len(scans)
                 else np.zeros(0, np.int64))
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

WHAT = f"{SCHEMA}/{VERSION} scan set"
MAX_ORIENTATION = 7  # orientations are multiples of 45 degrees: 0..7


def parse_meta(arrays: dict, name: str) -> dict:
    """The checked ``meta`` object: schema, version, history, sensor, units and sample rate."""
    meta = checks.schema_meta(arrays, name, SCHEMA, VERSION, "scan set")
    sensor = checks.meta_field(meta, "sensor", name, (dict,), "an object (the sensor layout)") or {}
    taxels = checks.meta_field(sensor, "taxels", name, (int,), "a whole number", prefix="sensor.")
    if taxels is not None and taxels < 1:
        raise DataError(f"{name}: meta 'sensor.taxels' must be at least 1, got {taxels}")
    checks.meta_field(meta, "units", name, (dict,), "an object (units of pose, force, time)")
    rate = checks.meta_field(meta, "sample_rate_hz", name, (int, float), "a number of samples per second")
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise DataError(f"{name}: meta 'sample_rate_hz' must be positive and finite, got {rate}")
    return meta


def _labels_from(arrays: dict, name: str) -> list[LabelVolume]:
    shapes = checks.numbers(checks.require(arrays, "label_shape", name, WHAT), "label_shape", name,
                            integer=True)
    checks.shape(shapes, "label_shape", name, (None, 3), "(L, 3): D, H, W of each label volume")
    if shapes.size and shapes.min() < 1:
        raise DataError(f"{name}: 'label_shape' must be at least 1 voxel on each axis, found "
                        f"{int(shapes.min())}")
    n = len(shapes)
    data = checks.require(arrays, "label_data", name, WHAT)
    checks.shape(data, "label_data", name, (None,), "(V,): the volumes flattened one after another")
    sizes = shapes.prod(axis=1)
    if data.shape[0] != sizes.sum():
        raise DataError(f"{name}: 'label_data' has {data.size} values, 'label_shape' needs "
                        f"{int(sizes.sum())}")
    check_codes(data, f"{name}: 'label_data'")
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    geometry = {}
    for key in ("label_origin_mm", "label_spacing_mm"):
        geometry[key] = checks.numbers(checks.require(arrays, key, name, WHAT), key, name)
        checks.shape(geometry[key], key, name, (n, 3), f"({n}, 3): z, y, x per label volume")
    checks.finite(geometry["label_origin_mm"], "label_origin_mm", name, "label volume")
    checks.positive(geometry["label_spacing_mm"], "label_spacing_mm", name, "label volume")
    names = checks.text_array(arrays.get("label_name", np.array([""] * n)), "label_name", name,
                              "volume names")
    checks.shape(names, "label_name", name, (n,), f"({n},)")
    return [LabelVolume(data[offsets[i]:offsets[i + 1]].reshape(shapes[i]), geometry["label_origin_mm"][i],
                        geometry["label_spacing_mm"][i], str(names[i])) for i in range(n)]


def _steps(arrays: dict, name: str, meta: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """pose (N, 6), force (N, T, 3) and time_s (N,), checked for type, shape and finite values."""
    pose = checks.numbers(checks.require(arrays, "pose", name, WHAT), "pose", name, dtype=np.float32)
    force = checks.numbers(checks.require(arrays, "force", name, WHAT), "force", name, dtype=np.float32)
    checks.shape(pose, "pose", name, (None, 6), "(N, 6)")
    checks.shape(force, "force", name, (None, None, 3), "(N, T, 3)")
    n = pose.shape[0]
    if force.shape[0] != n:
        raise DataError(f"{name}: 'force' has {force.shape[0]} steps but 'pose' has {n}")
    taxels = (meta.get("sensor") or {}).get("taxels")
    if taxels is not None and force.shape[1] != taxels:
        raise DataError(f"{name}: 'force' has {force.shape[1]} taxels, meta sensor says {taxels}")
    time_s = checks.numbers(arrays.get("time_s", np.zeros(n)), "time_s", name)
    checks.shape(time_s, "time_s", name, (n,), f"({n},)")
    for key, arr in (("pose", pose), ("force", force)):
        checks.finite(arr, key, name, dtype=np.float32)  # stored and computed in float32
    checks.finite(time_s, "time_s", name)
    return pose, force, time_s


def _trajectories(arrays: dict, name: str, n: int, n_scans: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """traj_offsets (R+1,), traj_scan (R,) and the per-trajectory attributes, checked."""
    offsets = checks.numbers(checks.require(arrays, "traj_offsets", name, WHAT), "traj_offsets", name,
                             integer=True)
    if (offsets.ndim != 1 or offsets.size < 1 or offsets[0] != 0 or offsets[-1] != n
        or np.any(np.diff(offsets) < 0)):
        raise DataError(f"{name}: 'traj_offsets' must rise from 0 to the step count {n}")
    traj_scan = checks.numbers(checks.require(arrays, "traj_scan", name, WHAT), "traj_scan", name,
                               integer=True)
    checks.shape(traj_scan, "traj_scan", name, (offsets.size - 1,), f"({offsets.size - 1},)")
    if traj_scan.size and (np.any(np.diff(traj_scan) < 0) or traj_scan[0] < 0 or traj_scan[-1] >= n_scans):
        raise DataError(f"{name}: 'traj_scan' must be non-decreasing scan indices in 0..{n_scans - 1}")
    attrs = {}
    for key, kind in TRAJ_ATTRS.items():
        arr = arrays.get(f"traj_{key}")
        if arr is None:
            arr = np.full(traj_scan.shape, "" if kind is str else np.nan,
                          dtype=object if kind is str else kind)
        elif kind is str:
            arr = checks.text_array(arr, f"traj_{key}", name, "names")
        else:
            arr = checks.numbers(arr, f"traj_{key}", name)
        checks.shape(np.asarray(arr), f"traj_{key}", name, traj_scan.shape, str(traj_scan.shape))
        attrs[key] = np.asarray(arr).astype(kind)
    return offsets, traj_scan, attrs


def validate(arrays: dict, name: str) -> ScanSet:
    """Check every key, shape, dtype and value; return the ScanSet or raise DataError naming the problem."""
    meta = parse_meta(arrays, name)
    pose, force, time_s = _steps(arrays, name, meta)
    scan_insert = checks.text_array(checks.require(arrays, "scan_insert", name, WHAT), "scan_insert", name,
                                    "insert names")
    checks.shape(scan_insert, "scan_insert", name, (None,), "(S,)")
    n_scans = scan_insert.shape[0]
    offsets, traj_scan, attrs = _trajectories(arrays, name, pose.shape[0], n_scans)
    labels = _labels_from(arrays, name) if "label_shape" in arrays or "label_data" in arrays else []
    per_scan = {}
    for key, default in (("scan_orientation", 0), ("scan_label", -1)):
        per_scan[key] = checks.numbers(arrays.get(key, np.full(n_scans, default)), key, name, integer=True)
        checks.shape(per_scan[key], key, name, (n_scans,), f"({n_scans},): one entry per scan")
    checks.in_range(per_scan["scan_orientation"], "scan_orientation", name, 0, MAX_ORIENTATION,
                    " (multiples of 45 degrees)")
    checks.in_range(per_scan["scan_label"], "scan_label", name, -1, len(labels) - 1,
                    f" (-1 = no label, else one of the {len(labels)} label volumes)")
    return ScanSet(pose, force, time_s, offsets, traj_scan, scan_insert,                 # float32 from _steps
                   per_scan["scan_orientation"], per_scan["scan_label"], labels, attrs, meta)


# ---------------------------------------------------------------------------------------------- read / write

def load_scans(path: str) -> ScanSet:
    """Read and validate a scan set: a ``.npz`` file, ``-`` (stdin), or a directory of ``.npz`` shards."""
    if path != "-" and os.path.isdir(path):
        shards = sorted(f for f in os.listdir(path) if f.endswith(".npz"))
        if not shards:
            raise DataError(f"{path}: directory holds no .npz shards")
        return concat([load_scans(os.path.join(path, f)) for f in shards], names=shards)
    return validate(read_npz(path, WHAT), "<stdin>" if path == "-" else path)


def to_arrays(scans: ScanSet) -> dict[str, np.ndarray]:
    """The ``.npz`` arrays of ``scans`` (inverse of ``validate``)."""
    labels = scans.labels
    arrays = {
        "pose": scans.pose.astype(np.float32, copy=False),
        "force": scans.force.astype(np.float32, copy=False),
        "time_s": scans.time_s.astype(np.float64, copy=False),
        "traj_offsets": scans.traj_offsets.astype(np.int64, copy=False),
        "traj_scan": scans.traj_scan.astype(np.int64), "scan_insert": scans.scan_insert.astype(str),
        "scan_orientation": scans.scan_orientation.astype(np.int64),
        "scan_label": scans.scan_label.astype(np.int64),
        "label_data": np.concatenate([v.data.ravel() for v in labels]) if labels else np.zeros(0, np.uint8),
        "label_shape": np.array([v.shape for v in labels], np.int64).reshape(-1, 3),
        "label_origin_mm": np.array([v.origin_mm for v in labels], np.float64).reshape(-1, 3),
        "label_spacing_mm": np.array([v.spacing_mm for v in labels], np.float64).reshape(-1, 3),
        "label_name": np.array([v.name for v in labels], dtype=str), "meta": np.array(json.dumps(scans.meta)),
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
        write_npz(tmp, arrays, compress)


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

    return ScanSet(cat("pose"), cat("force"), cat("time_s"), np.concatenate(traj_offsets),
                   np.concatenate(traj_scan), cat("scan_insert"), cat("scan_orientation"),
                   np.concatenate(scan_label), labels,
                   {k: np.concatenate([p.traj_attrs[k] for p in parts]) for k in TRAJ_ATTRS},
                   {**first, "history": history, "sample_rate_hz": _common_rate(parts)})


def _common_rate(parts: list[ScanSet]) -> float | None:
    """The parts' ``sample_rate_hz`` when they all agree, else None (mixed rates)."""
    rates = {p.meta.get("sample_rate_hz") for p in parts}
    return rates.pop() if len(rates) == 1 else None
