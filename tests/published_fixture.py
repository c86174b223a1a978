"""Small HDF5 fixtures in the published layout (REFERENCE.md), written by the tests themselves.

Layout written by :func:`write_root`::

    root/poke_trial/phantomA_St12C13_0.hdf5      3 trajectories (robot poses)
    root/poke_trial/phantomA_St12C13_2.hdf5
    root/poke_trial/phantomA_St10D5_1.hdf5
    root/primitives_trial/phantomA_St10D5_3.hdf5 with 'primitive' attributes
    root/mri_images_3D/st12c13_0.npy, st12c13_1.npy, st10d5_0.npy   (26, 128, 128) raw 0/127/200/255

:func:`write_hand_held_root` writes files carrying both ``robot`` and ``pos_estimation`` groups, the
latter in a tracker frame related by ``est_to_robot_calibration.npz``, so both imports must agree.
:func:`zip_root` and :func:`write_archive` pack such roots the way the archive publishes them (one
top folder per zip).
"""

from __future__ import annotations

import os
import zipfile

import h5py
import numpy as np

SENSOR_DT_S = 0.01
ROBOT_DT_S = 0.004
HOVER_S, DESCENT_S, RISE_S = 0.4, 1.0, 0.6
DESCENT_MM_S = 8.0
REF_POS_M = np.array([0.45, -0.10, 0.20])
LABEL_SHAPE = (26, 128, 128)
BASELINE_COUNTS = 12000.0
COUNTS_PER_MM = 150.0


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


REF_ROT = rot_z(0.3)


def depth_profile_mm(t_s: np.ndarray) -> np.ndarray:
    """Pad depth below its start (mm, >= 0): hover, descend at DESCENT_MM_S, rise back."""
    down = np.clip(t_s - HOVER_S, 0, DESCENT_S) * DESCENT_MM_S
    up = np.clip(t_s - HOVER_S - DESCENT_S, 0, RISE_S) * DESCENT_S * DESCENT_MM_S / RISE_S
    return down - up


def robot_trajectory(xy_local_mm, yaw_rad: float, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame positions (m) and rotations of a poke at reference-frame (x, y) mm, yaw rad."""
    local = np.zeros((len(t_s), 3))
    local[:, :2] = np.asarray(xy_local_mm) / 1000.0
    local[:, 2] = 0.002 - depth_profile_mm(t_s) / 1000.0
    pos = local @ REF_ROT.T + REF_POS_M  # inverse of the recentring p <- (p - t_ref) R_ref
    rot = np.repeat((REF_ROT @ rot_z(yaw_rad))[None], len(t_s), axis=0)
    return pos, rot


def write_traj(group, rng: np.random.Generator, xy_mm, yaw_rad: float, sensor_t0: float = 1000.0,
               robot_t0: float = 2000.0, hand_held_calib: dict | None = None,
               primitive: str | None = None) -> None:
    """One ``traj_<i>`` group: sensor 100 Hz, robot 250 Hz, clocks with different origins."""
    total = HOVER_S + DESCENT_S + RISE_S
    t_sensor = np.arange(0, total + 0.05, SENSOR_DT_S)
    t_robot = np.arange(0, total, ROBOT_DT_S)
    pos, rot = robot_trajectory(xy_mm, yaw_rad, t_robot)
    depth = depth_profile_mm(t_sensor) - 2.0
    counts = np.full((len(t_sensor), 30, 3), BASELINE_COUNTS) + rng.normal(0, 3, (len(t_sensor), 30, 3))
    counts[..., 2] += np.clip(depth, 0, None)[:, None] * COUNTS_PER_MM
    group.create_dataset("xela/data", data=counts.reshape(len(t_sensor), 90).astype(np.float64))
    group.create_dataset("xela/timestamps", data=t_sensor + sensor_t0)
    group.create_dataset("robot/ee_position", data=pos)
    group.create_dataset("robot/ee_rotation", data=rot)
    group.create_dataset("robot/timestamps", data=t_robot + robot_t0)
    if hand_held_calib is not None:
        r_pos, t_pos, r_ori = (hand_held_calib[k] for k in ("r_pos", "t_pos", "R_ori"))
        group.create_dataset("pos_estimation/ee_position", data=(pos - t_pos) @ r_pos)
        group.create_dataset("pos_estimation/ee_rotation", data=rot @ r_ori.T)
        group.create_dataset("pos_estimation/timestamps", data=t_robot + robot_t0 + 7.0)
    group.attrs.update({"force": 3.0, "angle": float(np.rad2deg(yaw_rad)), "dx": 0.001, "dy": -0.002})
    if primitive:
        group.attrs["primitive"] = primitive


def write_scan(path: str, rng: np.random.Generator, n_traj: int = 3, **kwargs) -> None:
    """One scan file with ``n_traj`` pokes at different places and yaws."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with h5py.File(path, "w") as h5:
        h5.attrs["position"] = REF_POS_M
        h5.attrs["orientation"] = REF_ROT.reshape(9)
        for i in range(n_traj):
            write_traj(h5.create_group(f"traj_{i}"), rng, (-10.0 + 8 * i, 5.0 - 3 * i), 0.2 * i, **kwargs)


def raw_label(rng: np.random.Generator, centre_xy_px=(90, 64)) -> np.ndarray:
    """(26, 128, 128) raw label: insert disc, a pillar and an inclusion at a column/row of the canvas."""
    _d, h, w = LABEL_SHAPE
    yy, xx = np.mgrid[0:h, 0:w]
    raw = np.zeros(LABEL_SHAPE, np.uint8)
    raw[:, (yy - 63.5) ** 2 + (xx - 63.5) ** 2 < 60**2] = 127
    cx, cy = centre_xy_px
    raw[:12, (yy - cy) ** 2 + (xx - cx) ** 2 < 3**2] = 200
    raw[10:20, (yy - cy) ** 2 + (xx - cx) ** 2 < 10**2] = 255
    return raw


def write_labels(root: str, rng: np.random.Generator) -> None:
    folder = os.path.join(root, "mri_images_3D")
    os.makedirs(folder, exist_ok=True)
    np.save(os.path.join(folder, "st12c13_0.npy"), raw_label(rng, (90, 64)))
    np.save(os.path.join(folder, "st12c13_1.npy"), raw_label(rng, (88, 64)))
    np.save(os.path.join(folder, "st10d5_0.npy"), raw_label(rng, (64, 40)))


def write_root(root: str, seed: int = 0, n_traj: int = 3) -> str:
    """The default fixture root (4 scan files, labels); returns ``root``."""
    rng = np.random.default_rng(seed)
    for name in ("phantomA_St12C13_0", "phantomA_St12C13_2", "phantomA_St10D5_1"):
        write_scan(os.path.join(root, "poke_trial", f"{name}.hdf5"), rng, n_traj)
    write_scan(os.path.join(root, "primitives_trial", "phantomA_St10D5_3.hdf5"), rng, n_traj, primitive="jab")
    write_labels(root, rng)
    return root


def calibration() -> dict:
    """A non-trivial tracker-to-robot calibration."""
    return {"r_pos": rot_z(0.7) @ rot_x(0.2), "t_pos": np.array([0.05, 0.02, -0.01]), "R_ori": rot_x(-0.4)}


def write_hand_held_root(root: str, seed: int = 0, n_traj: int = 2) -> str:
    """Hand-held files (robot + pos_estimation) and the calibration npz at the root."""
    rng = np.random.default_rng(seed)
    calib = calibration()
    os.makedirs(root, exist_ok=True)
    np.savez(os.path.join(root, "est_to_robot_calibration.npz"), **calib)
    write_scan(os.path.join(root, "handheld_trial", "phantomH_St12C13_1.hdf5"), rng, n_traj,
               hand_held_calib=calib)
    write_labels(root, rng)
    return root


def break_file(path: str, dataset: str = "robot/ee_position", traj: str = "traj_1") -> None:
    """Delete one dataset of one trajectory (a broken file)."""
    with h5py.File(path, "a") as h5:
        del h5[f"{traj}/{dataset}"]


def zip_root(root: str, path: str, top: str = "dataset", compression: int = zipfile.ZIP_DEFLATED) -> str:
    """Zip every file under ``root`` into ``path`` inside one top folder ``top`` (as published); returns
    ``path``."""
    with zipfile.ZipFile(path, "w", compression) as archive:
        for folder, _dirs, names in sorted(os.walk(root)):
            for name in sorted(names):
                full = os.path.join(folder, name)
                archive.write(full, f"{top}/{os.path.relpath(full, root)}")
    return path


def write_archive(path: str, seed: int = 0, n_traj: int = 2, compression: int = zipfile.ZIP_DEFLATED) -> str:
    """A published-style archive of two scans and their labels (built in a sibling folder); returns
    ``path``."""
    rng = np.random.default_rng(seed)
    root = f"{path}.src"
    for name in ("phantomA_St12C13_0", "phantomA_St10D5_1"):
        write_scan(os.path.join(root, "poke_trial", f"{name}.hdf5"), rng, n_traj)
    write_labels(root, rng)
    return zip_root(root, path, os.path.splitext(os.path.basename(path))[0], compression)
