"""Synthetic camera frames of AprilTags at known poses (for tests, demos and benchmarks).

Each tag is the bitmap from OpenCV's own marker generator (36h11: 8 x 8 cells including the black
border), printed on a white card with a quiet zone, placed in the camera frame by ``T_cam_tag`` (mm,
OpenCV marker frame: origin at the tag centre, x right, y up, z out of the tag). Pixels are rendered by
inverse mapping: each of ``supersample``^2 sub-pixel samples is undistorted into a camera ray, the ray
meets the tag plane, and the bitmap is looked up there; pixel centres sit at integer coordinates
(OpenCV's convention). Then lighting (gain and a linear gradient), Gaussian blur and sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lesscli.geometry import rotations
from lesscli.vision import se3
from lesscli.vision.camera import Camera
from lesscli.vision.detect import DICTIONARY, marker_cells

UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
MIN_RAY_DOT = 1e-6          # rays nearly parallel to the tag plane miss it


@dataclass(frozen=True)
class RenderEffects:
    """Image effects; each frame draws its lighting from the given ranges.

    Attributes:
        blur_px: Gaussian blur sigma, px (optics and focus).
        noise_gray: sensor noise sigma, grey levels of 255.
        gain: (low, high) range of the overall illumination gain.
        gradient: maximum relative brightness change across the image (linear ramp).
        background_gray: mean background level of 255.
        ink: (black, white) reflectance of the printed tag.
        margin_cells: white quiet zone around the tag, in tag cells.
        supersample: sub-pixel samples per pixel side (anti-aliasing).
    """

    blur_px: float = 0.7
    noise_gray: float = 2.0
    gain: tuple[float, float] = (0.75, 1.0)
    gradient: float = 0.2
    background_gray: float = 90.0
    ink: tuple[float, float] = (0.08, 0.8)
    margin_cells: float = 1.5
    supersample: int = 8


@dataclass
class TagPlacement:
    """One tag in the scene: its id and ``T_cam_tag`` (4, 4), mm."""

    tag_id: int
    T_cam_tag: np.ndarray


def _tag_bitmap(tag_id: int) -> np.ndarray:
    """(N, N) float reflectance-free bitmap in {0, 1}, one pixel per cell (row 0 = top = +y)."""
    n = marker_cells()
    bitmap = cv2.aruco.generateImageMarker(DICTIONARY(), int(tag_id), n, borderBits=1)
    return bitmap.astype(np.float64) / 255.0


def project(camera: Camera, points_cam: np.ndarray) -> np.ndarray:
    """(n, 3) camera-frame points, mm -> (n, 2) distorted pixel coordinates."""
    pts = np.asarray(points_cam, np.float64).reshape(-1, 1, 3)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), camera.matrix, camera.dist_coeffs)
    return uv.reshape(-1, 2)


def _card_bbox(camera: Camera, T: np.ndarray, half_mm: float) -> tuple[int, int, int, int] | None:
    """Pixel bounding box (x0, y0, x1, y1), exclusive end, of the tag card; None if off-screen or behind."""
    corners = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], np.float64) * half_mm
    cam = corners @ T[:3, :3].T + T[:3, 3]
    if np.any(cam[:, 2] <= 0):
        return None
    uv = project(camera, cam)
    x0, y0 = np.floor(uv.min(axis=0)).astype(int) - 2
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, camera.width), min(y1, camera.height)
    return None if x0 >= x1 or y0 >= y1 else (x0, y0, x1, y1)


def _render_card(camera: Camera, place: TagPlacement, tag_size_mm: float, fx: RenderEffects,
                 bbox: tuple[int, int, int, int], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Reflectance and coverage (both (h, w) in [0, 1]) of one card over its bounding box.

    Sub-pixel samples are stratified and jittered: a regular grid would snap edges to 1/supersample px
    (a bias that never averages out on edges aligned with the pixel grid); jitter turns it into noise.
    """
    x0, y0, x1, y1 = bbox
    ss = fx.supersample
    h, w = y1 - y0, x1 - x0
    strata = np.arange(ss) / ss - 0.5
    uu = (np.arange(x0, x1)[None, None, :, None] + strata[None, None, None, :]
          + rng.uniform(0, 1.0 / ss, size=(h, ss, w, ss)))
    vv = (np.arange(y0, y1)[:, None, None, None] + strata[None, :, None, None]
          + rng.uniform(0, 1.0 / ss, size=(h, ss, w, ss)))
    pix = np.stack([uu.ravel(), vv.ravel()], -1).reshape(-1, 1, 2)
    norm = cv2.undistortPoints(pix, camera.matrix, camera.dist_coeffs,
                               criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
    rays = np.concatenate([norm, np.ones((norm.shape[0], 1))], axis=1)
    rot, trans = place.T_cam_tag[:3, :3], place.T_cam_tag[:3, 3]
    normal = rot[:, 2]
    denom = rays @ normal
    hit = np.abs(denom) > MIN_RAY_DOT
    lam = np.where(hit, (trans @ normal) / np.where(hit, denom, 1.0), -1.0)
    hit &= lam > 0
    local = (rays * lam[:, None] - trans) @ rot          # tag-frame coordinates, mm
    bitmap = _tag_bitmap(place.tag_id)
    n = bitmap.shape[0]
    half_tag = tag_size_mm / 2.0
    half_card = half_tag * (n + 2 * fx.margin_cells) / n
    on_card = hit & (np.abs(local[:, 0]) <= half_card) & (np.abs(local[:, 1]) <= half_card)
    col = np.floor((local[:, 0] + half_tag) / tag_size_mm * n).astype(int)
    row = np.floor((half_tag - local[:, 1]) / tag_size_mm * n).astype(int)
    in_tag = on_card & (col >= 0) & (col < n) & (row >= 0) & (row < n)
    value = np.ones(norm.shape[0])
    value[in_tag] = bitmap[row[in_tag], col[in_tag]]
    black, white = fx.ink
    refl = np.where(on_card, black + (white - black) * value, 0.0)
    shape = (y1 - y0, ss, x1 - x0, ss)
    cover = on_card.reshape(shape).mean(axis=(1, 3))
    refl_sum = refl.reshape(shape).mean(axis=(1, 3))
    return np.where(cover > 0, refl_sum / np.where(cover > 0, cover, 1.0), 0.0), cover


def render_frame(camera: Camera, tags: list[TagPlacement], tag_size_mm: float, rng: np.random.Generator,
                 effects: RenderEffects | None = None) -> np.ndarray:
    """Render one greyscale frame.

    Args:
        camera: intrinsics and distortion.
        tags: tags to draw (any order; nearer tags cover farther ones).
        tag_size_mm: side of the tag's black square, mm.
        rng: random generator for lighting and noise.
        effects: image effects (defaults: ``RenderEffects()``).

    Returns:
        (height, width) uint8 image.
    """
    fx = effects or RenderEffects()
    h, w = camera.height, camera.width
    gain = rng.uniform(*fx.gain)
    ramp_dir = rng.normal(size=2)
    ramp_dir /= max(np.linalg.norm(ramp_dir), 1e-12)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    ramp = ((xx / w - 0.5) * ramp_dir[0] + (yy / h - 0.5) * ramp_dir[1]) * fx.gradient
    light = 255.0 * gain * (1.0 + ramp)
    image = np.full((h, w), fx.background_gray / 255.0)
    for place in sorted(tags, key=lambda p: -p.T_cam_tag[2, 3]):
        n = marker_cells()
        half_card = tag_size_mm / 2.0 * (n + 2 * fx.margin_cells) / n
        bbox = _card_bbox(camera, place.T_cam_tag, half_card)
        if bbox is None:
            continue
        refl, cover = _render_card(camera, place, tag_size_mm, fx, bbox, rng)
        x0, y0, x1, y1 = bbox
        image[y0:y1, x0:x1] = cover * refl + (1.0 - cover) * image[y0:y1, x0:x1]
    image *= light
    if fx.blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), fx.blur_px)
    image += rng.normal(0.0, fx.noise_gray, size=image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def facing_rotation(tilt_rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation of a tag that faces the camera (x right, y up in the image, z towards the camera),
    then tilted by ``tilt_rotvec_rad`` (3,) about its own axes."""
    facing = np.diag([1.0, -1.0, -1.0])
    return facing @ rotations.rotvec_to_matrix(tilt_rotvec_rad)


def make_trajectory(rng: np.random.Generator, n_frames: int = 30, fps: float = 30.0,
                    max_tilt_deg: float = 35.0, step: int = 1) -> dict[str, np.ndarray]:
    """A smooth hand-held-like motion of the sensor tag beside a fixed global tag.

    The global tag sits about 0.5 m away, upper left, tilted 20-30 degrees; the sensor tag wanders
    0.35-0.7 m away, its tilt from facing the camera staying within ``max_tilt_deg``.

    Args:
        rng: random generator (phases and amplitudes).
        n_frames: frames to produce.
        fps: frame rate, Hz.
        max_tilt_deg: bound on the sensor tag's tilt away from facing the camera.
        step: take every ``step``-th frame of the 30 fps motion (sparser, more varied sets).

    Returns:
        dict with ``time_s`` (n,), ``T_cam_global`` (4, 4) and ``T_cam_sensor_tag`` (n, 4, 4), mm.
    """
    t = np.arange(n_frames) * step / fps
    phase = rng.uniform(0, 2 * np.pi, size=6)
    freq = rng.uniform(0.15, 0.4, size=6)
    wave = np.sin(2 * np.pi * freq[None, :] * t[:, None] + phase[None, :])
    pos = np.array([40.0, 10.0, 525.0]) + wave[:, :3] * np.array([90.0, 60.0, 170.0])
    tilt = wave[:, 3:] * np.deg2rad(max_tilt_deg) / np.sqrt(3.0) * 0.98
    rot = facing_rotation(tilt)
    glob_tilt = np.deg2rad(np.array([rng.uniform(20, 30), rng.uniform(-10, 10), rng.uniform(-15, 15)]))
    T_global = se3.make_T(facing_rotation(glob_tilt), np.array([-150.0, -90.0, 500.0]))
    return {"time_s": t, "T_cam_global": T_global, "T_cam_sensor_tag": se3.make_T(rot, pos)}


def load_trajectory(path: str) -> dict[str, np.ndarray]:
    """Read a trajectory ``.npz``: ``time_s`` (n,), ``T_cam_global`` (4, 4) or (n, 4, 4), ``T_cam_sensor_tag``
    (n, 4, 4)."""
    from lesscli.errors import DataError
    from lesscli.io.npfiles import read_npz

    arrays = read_npz(path, what="trajectory")
    missing = [k for k in ("time_s", "T_cam_global", "T_cam_sensor_tag") if k not in arrays]
    if missing:
        raise DataError(f"{path}: missing {', '.join(missing)} (a trajectory holds time_s (n,), "
                        "T_cam_global (4, 4) or (n, 4, 4), T_cam_sensor_tag (n, 4, 4), mm)")
    t = np.asarray(arrays["time_s"], np.float64)
    sensor = np.asarray(arrays["T_cam_sensor_tag"], np.float64)
    glob_T = np.asarray(arrays["T_cam_global"], np.float64)
    n = t.shape[0] if t.ndim == 1 else -1
    if sensor.shape != (n, 4, 4) or glob_T.shape not in ((4, 4), (n, 4, 4)):
        raise DataError(f"{path}: shapes time_s {t.shape}, T_cam_sensor_tag {sensor.shape}, T_cam_global "
                        f"{glob_T.shape} do not fit (n,), (n, 4, 4), (4, 4) or (n, 4, 4)")
    if not (np.isfinite(t).all() and np.isfinite(sensor).all() and np.isfinite(glob_T).all()):
        raise DataError(f"{path}: NaN or inf in the trajectory")
    return {"time_s": t, "T_cam_global": glob_T, "T_cam_sensor_tag": sensor}


def truth_of(traj: dict[str, np.ndarray], T_stag_sensor: np.ndarray) -> dict[str, np.ndarray]:
    """True sensor poses in the global tag's frame: ``T_G<-S = T_G<-C T_C<-Stag T_Stag<-S``."""
    T_gs = se3.inv_T(traj["T_cam_global"]) @ traj["T_cam_sensor_tag"] @ T_stag_sensor
    pos, rv = se3.T_to_pose(T_gs)
    return {"time_s": traj["time_s"], "position_mm": pos, "rotvec_rad": rv, "rotation": T_gs[:, :3, :3]}


def render_sequence(camera: Camera, traj: dict[str, np.ndarray], out_dir: str, rng: np.random.Generator,
                    tag_size_mm: float = 31.0, sensor_tag: int = 1, global_tag: int = 0,
                    effects: RenderEffects | None = None, T_stag_sensor: np.ndarray | None = None,
                    progress=None) -> int:
    """Render every frame of ``traj`` into ``out_dir`` as ``frame_00000.png`` ... plus ``timestamps.txt``,
    ``camera.json``, ``trajectory.npz`` and ``truth.npz`` (true sensor poses in the global tag's frame).

    Returns:
        the number of frames written.
    """
    import os

    from lesscli.vision.camera import save_camera

    T_stag_sensor = np.eye(4) if T_stag_sensor is None else T_stag_sensor
    traj = {**traj, "time_s": np.round(traj["time_s"], 6)}     # the precision of timestamps.txt
    n = traj["time_s"].shape[0]
    glob_T = np.broadcast_to(traj["T_cam_global"], (n, 4, 4))
    steps = range(n) if progress is None else progress(range(n))
    for i in steps:
        tags = [TagPlacement(global_tag, glob_T[i]), TagPlacement(sensor_tag, traj["T_cam_sensor_tag"][i])]
        image = render_frame(camera, tags, tag_size_mm, rng, effects)
        if not cv2.imwrite(os.path.join(out_dir, f"frame_{i:05d}.png"), image):
            raise OSError(f"{out_dir}: could not write frame {i}")
    with open(os.path.join(out_dir, "timestamps.txt"), "w", encoding="utf-8") as fh:
        fh.writelines(f"{t:.6f}\n" for t in traj["time_s"])
    save_camera(os.path.join(out_dir, "camera.json"), camera)
    np.savez(os.path.join(out_dir, "trajectory.npz"), time_s=traj["time_s"],
             T_cam_global=traj["T_cam_global"], T_cam_sensor_tag=traj["T_cam_sensor_tag"])
    truth = truth_of({**traj, "T_cam_global": glob_T}, T_stag_sensor)
    np.savez(os.path.join(out_dir, "truth.npz"), **truth, tag_size_mm=np.float64(tag_size_mm))
    return n
