"""Import of the published HDF5 layout (see ``REFERENCE.md``) into a ``less.scans/1`` scan set.

One HDF5 file per scan, ``<root>/<trial>/<phantom>_<insert>_<orientation>.hdf5``; 3D labels in
``<root>/mri_images_3D/<insert_lower>_<n>.npy``. Each trajectory goes through
:func:`lesscli.data.preprocess.preprocess`; each file becomes one scan. Poses stay in each file's
recentred right-handed frame (x, y in the surface plane, z up, mm). The published label canvas has x
flipped against the recorded positions, so the *label* is mirrored (:func:`label_volume`): negating pose
x instead would mirror the world and need shear forces, pitch, yaw and the taxel layout flipped too.
Which end of the published volume is the top is not documented, so it is an option (``top_slice``).
Forces stay raw sensor counts, baseline-removed, or become newtons with a stated calibration
(``counts_per_newton``, kept in ``meta.sensor.counts_per_n``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lesscli.data import preprocess as pp
from lesscli.data.sources import FolderSource, ZipSource, load_array, open_source
from lesscli.errors import DataError
from lesscli.io import checks
from lesscli.io.labels import LabelVolume
from lesscli.io.scans import ScanSet, concat, default_meta
from lesscli.io.sensor import xela_uscu

SPACING_MM = (0.9, 0.4774, 0.4774)
LABEL_INPLANE = (128, 128)   # published labels: the 61.1 mm field of view resampled to 128 x 128 px
LARGE_INPLANE_FACTOR = 2.0
SENSOR_TAXELS = 30
CALIBRATION_NAME = "est_to_robot_calibration.npz"
LABEL_DIR = "mri_images_3D"
_NAME = re.compile(r"^(?P<phantom>.+)_(?P<insert>[^_]+)_(?P<orientation>[0-7])\.hdf5$")


@dataclass
class ImportOptions:
    """Options of ``less import`` (see the command help)."""

    every: int = 1
    trajectories: int | None = None
    hand_held: bool = False
    calibration: str | None = None
    labels_dir: str | None = None
    mri_scan: int = 0
    top_slice: str = "last"
    counts_per_newton: float | None = None
    _calib_cache: dict = field(default_factory=dict, repr=False)
    _label_cache: dict = field(default_factory=dict, repr=False)


def find_scan_files(source: FolderSource | ZipSource) -> list[str]:
    """All ``*.hdf5`` files of the dataset, relative to its root, sorted."""
    return [rel for rel in source.files() if rel.endswith(".hdf5")]


def parse_scan_name(path: str) -> tuple[str, str, int]:
    """``<phantom>_<insert>_<orientation>.hdf5`` -> (phantom, insert, orientation)."""
    match = _NAME.match(os.path.basename(path))
    if not match:
        raise DataError(f"{path}: file name is not <phantom>_<insert>_<orientation 0-7>.hdf5")
    return match["phantom"], match["insert"], int(match["orientation"])


def is_large(insert: str) -> bool:
    """Large-phantom inserts are named like ``bst12d30``."""
    return insert.lower().startswith("b")


# ---------------------------------------------------------------------------------------------- HDF5

def _dataset(group, key: str, where: str) -> np.ndarray:
    try:
        return np.asarray(group[key][()])
    except KeyError:
        raise DataError(f"{where}: missing dataset '{key}'") from None


def _timestamps(arr: np.ndarray, n: int, key: str, where: str) -> np.ndarray:
    arr = np.asarray(arr, np.float64)
    if arr.shape != (n,):
        raise DataError(f"{where}: '{key}' has shape {arr.shape}, expected ({n},) to match its data")
    if not np.isfinite(arr).all() or np.any(np.diff(arr) < 0):
        raise DataError(f"{where}: '{key}' is not finite and non-decreasing (inconsistent timestamps)")
    return arr


def _finite(arr: np.ndarray, key: str, where: str) -> np.ndarray:
    if not np.isfinite(arr).all():
        raise DataError(f"{where}: '{key}' holds NaN or inf")
    return arr


def read_stream(group, where: str, pose_group: str) -> pp.Stream:
    """One ``traj_<i>`` group -> a checked :class:`Stream` (raises DataError naming the dataset)."""
    data = _dataset(group, "xela/data", where).astype(np.float64)
    if data.ndim != 2 or data.shape[1] != SENSOR_TAXELS * 3:
        raise DataError(f"{where}: 'xela/data' has shape {data.shape}, expected (N, {SENSOR_TAXELS * 3})")
    t_s = _timestamps(_dataset(group, "xela/timestamps", where), len(data), "xela/timestamps", where)
    pos = _dataset(group, f"{pose_group}/ee_position", where).astype(np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise DataError(f"{where}: '{pose_group}/ee_position' has shape {pos.shape}, expected (M, 3)")
    rot = _dataset(group, f"{pose_group}/ee_rotation", where).astype(np.float64)
    if rot.shape not in ((len(pos), 3, 3), (len(pos), 9)):
        raise DataError(f"{where}: '{pose_group}/ee_rotation' has shape {rot.shape}, expected ({len(pos)}, "
                        "3, 3)")
    t_r = _timestamps(_dataset(group, f"{pose_group}/timestamps", where), len(pos),
                      f"{pose_group}/timestamps", where)
    return pp.Stream(t_s, _finite(data, "xela/data", where).reshape(-1, SENSOR_TAXELS, 3), t_r,
                     _finite(pos, f"{pose_group}/ee_position", where),
                     _finite(rot, f"{pose_group}/ee_rotation", where).reshape(-1, 3, 3))


def _attr_float(attrs, key: str, scale: float = 1.0) -> float:
    return float(np.asarray(attrs[key]).reshape(-1)[0]) * scale if key in attrs else float("nan")


def _attr_str(attrs, key: str) -> str:
    value = attrs.get(key, "")
    return value.decode() if isinstance(value, bytes) else str(value)


def traj_attributes(attrs) -> dict:
    """Group attributes -> TRAJ_ATTRS values: ``force`` the target force (N), ``angle`` the yaw (degrees ->
    rad), ``dx``/``dy`` grid offsets (m -> mm), ``primitive``."""
    return {"target_force_n": _attr_float(attrs, "force"),
            "yaw_rad": _attr_float(attrs, "angle", np.pi / 180),
            "dx_mm": _attr_float(attrs, "dx", pp.M_TO_MM), "dy_mm": _attr_float(attrs, "dy", pp.M_TO_MM),
            "primitive": _attr_str(attrs, "primitive")}


def _traj_names(h5, path: str) -> list[str]:
    names = [k for k in h5 if re.fullmatch(r"traj_\d+", k)]
    if not names:
        raise DataError(f"{path}: no 'traj_<i>' groups")
    return sorted(names, key=lambda k: int(k.split("_")[1]))


def _reference_pose(h5, path: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        t_ref = np.asarray(h5.attrs["position"], np.float64).reshape(3)
        rot_ref = np.asarray(h5.attrs["orientation"], np.float64).reshape(3, 3)
    except KeyError as exc:
        raise DataError(f"{path}: missing file attribute {exc} (reference pose)") from None
    except ValueError:
        raise DataError(f"{path}: file attributes 'position' (3,) / 'orientation' (9,) have wrong "
                        "sizes") from None
    return t_ref, rot_ref


# ---------------------------------------------------------------------------------------------- calibration,
# labels

def load_calibration(source: FolderSource | ZipSource, rel: str) -> dict:
    """``est_to_robot_calibration.npz`` -> {'r_pos' (3,3), 't_pos' (3,), 'R_ori' (3,3)}."""
    arrays = load_array(source, rel, "calibration .npz")
    where = source.where(rel)
    try:
        calib = {k: checks.numbers(arrays[k], k, where) for k in ("r_pos", "t_pos", "R_ori")}
    except (KeyError, TypeError, IndexError) as exc:
        raise DataError(f"{where}: calibration lacks key {exc}") from None
    if calib["r_pos"].size != 9 or calib["t_pos"].size != 3 or calib["R_ori"].size != 9:
        raise DataError(f"{where}: calibration needs r_pos (3, 3), t_pos (3,), R_ori (3, 3)")
    for key, value in calib.items():
        checks.finite(value.reshape(1, -1), key, where, "array")
    return calib


def find_calibration(source: FolderSource | ZipSource, rel: str, opts: ImportOptions) -> dict:
    """The calibration for a hand-held file: ``opts.calibration`` or the nearest one up to the root."""
    if opts.calibration:
        folder, name = os.path.split(os.path.abspath(opts.calibration))
        candidates = [(FolderSource(folder), name)] if os.path.isfile(opts.calibration) else []
    else:
        parts = rel.split("/")[:-1]
        candidates = [(source, "/".join([*parts[:n], CALIBRATION_NAME])) for n in range(len(parts), -1, -1)]
    for cal_source, cal_rel in candidates:
        if cal_source.is_file(cal_rel):
            key = cal_source.where(cal_rel)
            if key not in opts._calib_cache:
                opts._calib_cache[key] = load_calibration(cal_source, cal_rel)
            return opts._calib_cache[key]
    raise DataError(f"{source.where(rel)}: hand-held import needs {CALIBRATION_NAME} (not found up to the "
                    "dataset root; pass --calibration)")


def label_volume(raw: np.ndarray, insert: str, orientation: int, name: str,
                 top_slice: str = "last") -> LabelVolume:
    """A published (D, H, W) label -> a LabelVolume in the pose frame for ``orientation``.

    Raw codes are mapped to 0..3, rotated by -45 deg x orientation on the canvas, mirrored along x
    (canvas x = -pose x; after the mirror the label is turned by +45 deg x orientation about z in the pose
    frame, the sense of the simulator's ``Phantom.rotated(k)``) and placed on the grid centred at x = y = 0
    with the top slice at z = 0, 0.9 mm apart (``top_slice``: "last" keeps the stored order with the last
    slice at z = 0, "first" flips the stack).
    """
    if raw.ndim != 3:
        raise DataError(f"{name}: label has shape {raw.shape}, expected (D, H, W)")
    if raw.shape[1:] != LABEL_INPLANE:
        raise DataError(f"{name}: label is {' x '.join(map(str, raw.shape))}, but the published layout is "
                        f"D x {LABEL_INPLANE[0]} x {LABEL_INPLANE[1]} (spacing {SPACING_MM[1]} mm in-plane); "
                        "a resampled or cropped label would get the wrong field of view, use the original "
                        "file")
    data = pp.rotate_label(pp.map_label_codes(raw, name), -pp.ORIENTATION_STEP_DEG * orientation)
    data = data[:, :, ::-1]
    if top_slice == "first":
        data = data[::-1]
    factor = LARGE_INPLANE_FACTOR if is_large(insert) else 1.0
    spacing = np.array([SPACING_MM[0], SPACING_MM[1] * factor, SPACING_MM[2] * factor])
    d, h, w = data.shape
    origin = np.array([-(d - 1) * spacing[0], -(h - 1) / 2 * spacing[1], -(w - 1) / 2 * spacing[2]])
    return LabelVolume(data, origin, spacing, f"{os.path.splitext(os.path.basename(name))[0]}_k{orientation}")


def find_label(source: FolderSource | ZipSource, insert: str, orientation: int,
               opts: ImportOptions) -> LabelVolume | None:
    """The label for (insert, orientation): scan ``opts.mri_scan`` or else the lowest one present."""
    key = (insert.lower(), orientation)
    if key in opts._label_cache:
        return opts._label_cache[key]
    labels, folder = (source, f"{LABEL_DIR}/") if not opts.labels_dir else (
        FolderSource(opts.labels_dir) if os.path.isdir(opts.labels_dir) else None, "")
    pattern = re.compile(rf"^{re.escape(folder.lower())}{re.escape(insert.lower())}_(\d+)\.npy$")
    found = sorted((int(m[1]), f) for f in (labels.files() if labels else [])
                   if (m := pattern.match(f.lower())))
    chosen = [f for n, f in found if n == opts.mri_scan] or [f for _n, f in found[:1]]
    volume = None
    if chosen:
        raw = load_array(labels, chosen[0], "label .npy")
        volume = label_volume(raw, insert, orientation, labels.where(chosen[0]), opts.top_slice)
    opts._label_cache[key] = volume
    return volume


# ---------------------------------------------------------------------------------------------- import

def _dropped() -> dict:
    return {"short": 0, "no_onset": 0, "too_long": 0}


def import_file(source: FolderSource | ZipSource, rel: str,
                opts: ImportOptions) -> tuple[ScanSet | None, dict]:
    """One HDF5 scan file (``rel`` in ``source``) -> (a one-scan ScanSet or None when nothing survives, its
    record).

    Raises DataError naming the file (and trajectory) when the file is broken.
    """
    import h5py

    path = source.where(rel)
    _phantom, insert, orientation = parse_scan_name(path)
    calib = find_calibration(source, rel, opts) if opts.hand_held else None
    pose_group = "pos_estimation" if opts.hand_held else "robot"
    max_steps = pp.MAX_STEPS_HAND_HELD if opts.hand_held else pp.MAX_STEPS_ROBOT
    kept, attrs, dropped = [], [], _dropped()
    with source.open(rel) as fh:
        try:
            h5 = h5py.File(fh, "r")
        except OSError as exc:
            raise DataError(f"{path}: not a readable HDF5 file ({exc})") from None
        with h5:
            t_ref, rot_ref = _reference_pose(h5, path)
            for name in _traj_names(h5, path):
                if opts.trajectories is not None and len(kept) >= opts.trajectories:
                    break
                out, traj_attrs = _read_traj(h5, name, path, pose_group, calib, t_ref, rot_ref, max_steps)
                if isinstance(out, str):
                    dropped[out] += 1
                    continue
                kept.append(out)
                attrs.append(traj_attrs)
    record = {"file": rel, "insert": insert, "orientation": orientation, "status": "ok",
              "trajectories": len(kept), "steps": 0, "dropped": dropped, "label": None, "error": None}
    if not kept:
        record["status"] = "empty"
        return None, record
    label = find_label(source, insert, orientation, opts)
    record["label"] = label.name if label is not None else None
    scans = _one_scan(kept, attrs, insert, orientation, label, opts.every)
    record["steps"] = scans.n_steps
    return scans, record


def _read_traj(h5, name: str, path: str, pose_group: str, calib: dict | None, t_ref: np.ndarray,
               rot_ref: np.ndarray, max_steps: int) -> tuple[pp.Processed | str, dict]:
    """One ``traj_<i>`` group -> (preprocessed trajectory, or the reason it was dropped; its attributes)."""
    try:
        stream = read_stream(h5[name], f"{path}: {name}", pose_group)
        traj_attrs = traj_attributes(h5[name].attrs)
    except (KeyError, TypeError, ValueError, OSError, AttributeError) as exc:
        raise DataError(f"{path}: {name}: unreadable ({type(exc).__name__}: {exc})") from None
    if calib is not None:
        stream.robot_pos_m, stream.robot_rot = pp.calibrate_estimate(stream.robot_pos_m, stream.robot_rot,
                                                                     calib)
    out, reason = pp.preprocess(stream, t_ref, rot_ref, max_steps)
    return (reason if out is None else out), traj_attrs


def _one_scan(trajs: list[pp.Processed], attrs: list[dict], insert: str, orientation: int,
              label: LabelVolume | None, every: int) -> ScanSet:
    trajs = [pp.Processed(t.pose[::every], t.force[::every], t.time_s[::every]) for t in trajs]
    lengths = np.array([len(t.pose) for t in trajs], np.int64)
    traj_attrs = {key: np.array([a[key] for a in attrs]) for key in attrs[0]}
    traj_attrs = {k: (v.astype(str) if k == "primitive" else v.astype(np.float32)) for k,
                  v in traj_attrs.items()}
    return ScanSet(
        pose=np.concatenate([t.pose for t in trajs]), force=np.concatenate([t.force for t in trajs]),
        time_s=np.concatenate([t.time_s for t in trajs]),
        traj_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        traj_scan=np.zeros(len(trajs), np.int64), scan_insert=np.array([insert]),
        scan_orientation=np.array([orientation], np.int64),
        scan_label=np.array([0 if label is not None else -1], np.int64),
        labels=[label] if label is not None else [], traj_attrs=traj_attrs, meta=import_meta(every, False))


def import_meta(every: int, hand_held: bool, counts_per_newton: float | None = None) -> dict:
    """``meta`` of an imported scan set: counts as force unit (newtons with a calibration, recorded in
    ``sensor.counts_per_n``), 100 Hz / every, how it was made."""
    sensor, units, force = (xela_uscu(), "counts",
                            "raw sensor counts, first sample of each trajectory subtracted")
    if counts_per_newton:
        sensor, units = {**sensor, "counts_per_n": float(counts_per_newton)}, "N"
        force = f"newtons: raw sensor counts / {counts_per_newton:g} counts per N, first sample subtracted"
    return default_meta(sensor, force_units=units, sample_rate_hz=100.0 / every,
                        source={"layout": "published-hdf5", "hand_held": hand_held, "every": every,
                                "force": force,
                                "frame": "recentred on each file's reference pose; labels mirrored in x"})


def import_published(root: str, opts: ImportOptions, shard: tuple[int, int] = (0, 1), on_error: str = "fail",
                     progress: Callable | None = None,
                     report: Callable[[dict], None] | None = None) -> ScanSet:
    """Import every scan file of shard ``i/n`` of the dataset at ``root`` into one scan set.

    Args:
        root: dataset root folder, or a zip archive of it (read in place, see :mod:`lesscli.data.sources`).
        opts: import options.
        shard: (i, n): files i, i+n, i+2n, ... of the sorted list.
        on_error: "fail" raises on the first broken file; "skip" reports it and goes on.
        progress: wraps the file list (a progress bar), e.g. ``lesscli.cli.common.progress``.
        report: called with one record per file (status ok / empty / skipped).

    Raises:
        DataError: a broken file with ``on_error="fail"``, or no scan survived.
    """
    source = open_source(root)
    try:
        return _import_files(source, root, opts, shard, on_error, progress, report)
    finally:
        source.close()


def _import_files(source, root, opts, shard, on_error, progress, report) -> ScanSet:
    files = find_scan_files(source)[shard[0]::shard[1]]
    if not files:
        raise DataError(f"{root}: no *.hdf5 scan files (shard {shard[0]}/{shard[1]})")
    parts, names = [], []
    for rel in (progress(files, desc="import", unit="file") if progress else files):
        try:
            scans, record = import_file(source, rel, opts)
        except DataError as exc:
            if on_error == "fail":
                raise
            _phantom, insert, orientation = _safe_name(rel)
            scans, record = None, {"file": rel, "insert": insert, "orientation": orientation,
                                   "status": "skipped", "trajectories": 0, "steps": 0, "dropped": _dropped(),
                                   "label": None, "error": str(exc)}
        if report:
            report(record)
        if scans is not None:
            parts.append(scans)
            names.append(source.where(rel))
    if not parts:
        raise DataError(f"{root}: no scan survived the import ({len(files)} files; see the per-file records)")
    out = concat(parts, names)
    out.meta = import_meta(opts.every, opts.hand_held, opts.counts_per_newton)
    if opts.counts_per_newton:
        out.force = (out.force.astype(np.float64) / opts.counts_per_newton).astype(out.force.dtype)
    return out


def _safe_name(path: str) -> tuple[str, str, int | None]:
    try:
        return parse_scan_name(path)
    except DataError:
        return "", "", None
