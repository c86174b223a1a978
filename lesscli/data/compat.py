"""What a model was trained on, and whether a scan set fits it: units, sensor layout, pose frame,
plausibility.

A checkpoint keeps the *data signature* of its training set (``norm_stats['data']``, written by
:func:`lesscli.data.batching.compute_norm_stats`; ``config['data']`` of a force-map calibration): the force
units, the pose units, the sensor's taxel layout and the pose frame its imager reads (``surface``: poses on
the surface fitted from the contact onsets, :mod:`lesscli.data.surface`). :func:`for_model` checks a scan set
against it, refusing any difference in one line naming both files, and hands back the scans in the
model's frame. :func:`check_plausible` refuses values no tactile scan holds (poses in metres read as
millimetres, degrees read as radians, forces in counts read as newtons), with the sensor's own force
range where its file gives one (``meta['sensor']['max_force_n']``).
"""

from __future__ import annotations

import numpy as np

from lesscli.errors import DataError

POSE_UNITS = ["mm", "mm", "mm", "rad", "rad", "rad"]
MAX_POSE_MM = 1000.0         # a pose further than this from the phantom's centre is not a touch
MAX_ANGLE_RAD = 2 * np.pi    # roll/pitch/yaw beyond a full turn: degrees read as radians
MAX_FORCE_N = 200.0          # per taxel, when the sensor file gives no max_force_n
LAYOUT_TOL_MM = 1e-3
SENSOR_KEYS = ("name", "pitch_mm", "pad_size_mm", "noise_n", "max_force_n", "counts_per_n")


def signature(scans, frame: str | None = None) -> dict:
    """The data signature of a scan set: force and pose units, taxel layout, pose frame."""
    units = scans.meta.get("units") or {}
    sensor = scans.meta.get("sensor") or {}
    xy = sensor.get("taxel_xy_mm")
    return {"force_units": str(units.get("force", "N")), "pose_units": list(units.get("pose", POSE_UNITS)),
            "taxel_xy_mm": None if xy is None
            else np.asarray(xy, np.float64).reshape(-1, 2).round(6).tolist(),
            "taxels": int(scans.n_taxels), "pose_frame": frame or scans.meta.get("pose_frame", "phantom"),
            "sensor": {k: sensor[k] for k in SENSOR_KEYS if sensor.get(k) is not None}}


def model_signature(ckpt: dict) -> dict:
    """A checkpoint's data signature; a checkpoint written before signatures has only its force units
    (when recorded) and the phantom frame."""
    stats = ckpt.get("norm_stats") or {}
    sig = stats.get("data") or (ckpt.get("config") or {}).get("data")
    if isinstance(sig, dict):
        return sig
    return {"force_units": stats.get("force_units") or None, "pose_frame": "phantom"}


def differences(expected: dict, got: dict) -> list[str]:
    """What differs between two signatures (keys missing on either side are not compared)."""
    out = []
    for key, what in (("force_units", "force units"), ("pose_units", "pose units")):
        a, b = expected.get(key), got.get(key)
        if a and b and a != b:
            out.append(f"{what} {_show(b)} vs {_show(a)}")
    a, b = expected.get("taxel_xy_mm"), got.get("taxel_xy_mm")
    if a is not None and b is not None:
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        if a.shape != b.shape or np.abs(a - b).max() > LAYOUT_TOL_MM:
            out.append(f"taxel layout {len(b)} taxels vs {len(a)} taxels" if a.shape != b.shape
                       else f"taxel layout differs (up to {np.abs(a - b).max():.3g} mm)")
    elif expected.get("taxels") and got.get("taxels") and expected["taxels"] != got["taxels"]:
        out.append(f"taxel layout {got['taxels']} taxels vs {expected['taxels']} taxels")
    return out


def _show(value) -> str:
    return "'" + (",".join(value) if isinstance(value, list) else str(value)) + "'"


def check_match(expected: dict, scans, model_name: str, scans_name: str) -> None:
    """DataError in one line naming both files unless ``scans`` matches the signature ``expected``."""
    diff = differences(expected, signature(scans))
    if diff:
        hint = "convert the forces (less import --counts-per-newton) or use" if "force" in diff[0] else "use"
        raise DataError(f"{scans_name} does not match {model_name}: {'; '.join(diff)} (scans vs model); "
                        f"{hint} a model trained on such scans")


def check_plausible(scans, name: str) -> None:
    """DataError naming ``name`` when poses, angles or forces lie outside what a tactile scan can hold."""
    units = (scans.meta.get("units") or {})
    pose_units = list(units.get("pose", POSE_UNITS))
    if pose_units != POSE_UNITS:
        raise DataError(f"{name}: poses are in {','.join(pose_units)}; the toolkit reads "
                        f"{','.join(POSE_UNITS)} (convert with less import, or fix meta.units.pose)")
    if not scans.n_steps:
        return
    pose = np.asarray(scans.pose, np.float64)
    far = np.abs(pose[:, :3]).max()
    if far > MAX_POSE_MM:
        raise DataError(f"{name}: a pose lies {far:.4g} mm from the phantom's centre (more than "
                        f"{MAX_POSE_MM:g}); are the poses in metres or micrometres rather than mm?")
    turn = np.abs(pose[:, 3:]).max()
    if turn > MAX_ANGLE_RAD:
        raise DataError(f"{name}: an angle of {turn:.4g} rad (more than a full turn); are the angles in "
                        "degrees?")
    sensor = scans.meta.get("sensor") or {}
    top = float(sensor.get("max_force_n") or MAX_FORCE_N)
    if units.get("force", "N") == "counts":
        top *= float(sensor.get("counts_per_n") or 0.0) or np.inf
    peak = float(np.abs(np.asarray(scans.force, np.float64)).max())
    if peak > top:
        raise DataError(f"{name}: a taxel reads {peak:.4g} {units.get('force', 'N')} (more than {top:g}); "
                        "are the forces in sensor counts? (less import --counts-per-newton converts them)")


def prepare(scans, name: str, frame: str = "surface"):
    """A scan set checked for plausibility and put in ``frame`` (``surface`` or ``phantom``)."""
    from lesscli.data.surface import FRAME, surface_frame

    check_plausible(scans, name)
    return surface_frame(scans) if frame == FRAME else scans


def for_model(scans, ckpt: dict, model_name: str, scans_name: str):
    """The scans checked against the checkpoint's signature and in the frame its imager reads."""
    sig = model_signature(ckpt)
    check_match(sig, scans, model_name, scans_name)
    return prepare(scans, scans_name, sig.get("pose_frame", "phantom"))
