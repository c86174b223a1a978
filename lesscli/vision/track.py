"""Track the sensor in the global tag's frame: ``T_G<-S = T_G<-C T_C<-Stag T_Stag<-S`` per frame.

Two passes: first every frame is read and its tags detected; then poses are solved. The global tag is
fixed and so is the camera, so by default (``global_mode="static"``) its pose comes from ONE PnP over its
corners from all frames (stacked), which removes most of its per-frame noise; ``"per-frame"`` solves it
in each frame instead; a frame whose global-tag corners sit more than ``GLOBAL_OUTLIER_PX`` from their
median (the camera was bumped) is solved on its own and says so in ``note``. Each tag's planar ambiguity
is settled by reprojection error and, when IPPE's two solutions are close, by consistency with the
previous frame's rotation.
"""

from __future__ import annotations

import glob
import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.vision import se3
from lesscli.vision.camera import Camera
from lesscli.vision.detect import (
    TagDetector,
    TagPose,
    refine_pose,
    reprojection_rms,
    solve_tag_pose,
    tag_object_points,
)

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
# a frame whose global-tag corners sit this far from the median is left out of the fit
GLOBAL_OUTLIER_PX = 2.0
ORTHO_TOL = 1e-3            # |R^T R - I| tolerance for a tag-to-sensor rotation
UNREADABLE = "unreadable image"  # the note of a frame that could not be decoded

@dataclass
class Frame:
    """One input frame: index, time (s), name, and the image (None if unreadable, with ``note``)."""

    index: int
    time_s: float
    name: str
    image: np.ndarray | None
    note: str = ""


@dataclass
class TrackOptions:
    sensor_tag: int = 1
    global_tag: int = 0
    tag_size_mm: float = 31.0
    refine: str = "apriltag"
    global_mode: str = "static"
    T_stag_sensor: np.ndarray = field(default_factory=lambda: np.eye(4))


def read_timestamps(path: str, names: list[str]) -> np.ndarray:
    """``timestamps.txt``: one time (s) per image in name order, or lines ``NAME TIME``."""
    by_name, plain = {}, []
    with open(path, encoding="utf-8") as fh:
        for number, line in enumerate(fh, start=1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            try:
                value = float(parts[0] if len(parts) == 1 else parts[1])
            except ValueError:
                raise DataError(f"{path}: line {number} is not 'TIME' or 'NAME TIME' in seconds") from None
            if not math.isfinite(value):
                raise DataError(f"{path}: line {number}: the time is {parts[-1]!r}; times must be finite "
                                "seconds")
            if len(parts) == 1:
                plain.append(value)
            else:
                by_name[parts[0]] = value
    if by_name:
        missing = [n for n in names if n not in by_name]
        if missing:
            raise DataError(f"{path}: no time for image '{missing[0]}' ({len(missing)} images without a "
                            "time)")
        times = np.array([by_name[n] for n in names])
    elif len(plain) != len(names):
        raise DataError(f"{path}: {len(plain)} times for {len(names)} images")
    else:
        times = np.array(plain)
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise DataError(f"{path}: image '{names[i]}' has time {times[i]:g} s, not after '{names[i - 1]}' "
                        f"({times[i - 1]:g} s); times must rise in the images' name order")
    return times


def _image_frames(folder: str, fps: float | None) -> Iterator[Frame]:
    names = sorted(os.path.basename(p) for p in glob.glob(os.path.join(folder, "*"))
                   if p.lower().endswith(IMAGE_EXTS))
    if not names:
        raise DataError(f"{folder}: no images ({', '.join(IMAGE_EXTS)}) in this folder")
    stamp_file = os.path.join(folder, "timestamps.txt")
    if fps is not None:
        times = np.arange(len(names)) / fps
    elif os.path.exists(stamp_file):
        times = read_timestamps(stamp_file, names)
    else:
        raise DataError(f"{folder}: no timestamps.txt; give the frame rate with --fps")
    for i, name in enumerate(names):
        image = cv2.imread(os.path.join(folder, name), cv2.IMREAD_GRAYSCALE)
        yield Frame(i, float(times[i]), name, image, "" if image is not None else UNREADABLE)


def _video_frames(path: str, fps: float | None) -> Iterator[Frame]:
    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        raise DataError(f"{path}: not a readable video or image folder")
    rate = fps or cap.get(cv2.CAP_PROP_FPS) or 0.0
    if rate <= 0:
        cap.release()
        raise DataError(f"{path}: the video does not state its frame rate; give --fps")
    try:
        i = 0
        while True:
            ok, image = cap.read()
            if not ok:
                break
            yield Frame(i, i / rate, f"{os.path.basename(path)}#{i}", cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
            i += 1
    finally:
        cap.release()


def iter_frames(path: str, fps: float | None = None) -> Iterator[Frame]:
    """Frames of a folder of images (sorted by name) or of a video file."""
    if fps is not None and fps <= 0:
        raise DataError(f"--fps must be positive (got {fps})")
    if os.path.isdir(path):
        return _image_frames(path, fps)
    if not os.path.exists(path):
        raise DataError(f"{path}: no such folder or video file")
    return _video_frames(path, fps)


def load_tag_to_sensor(path: str) -> np.ndarray:
    """``T_Stag<-S`` (4, 4) mm from JSON: a 4x4 list, or ``{"T": ...}``; checked to be rigid."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not valid JSON ({exc.msg})") from None
    if isinstance(data, dict):
        data = data.get("T", data.get("T_stag_sensor"))
    try:
        T = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise DataError(f"{path}: expected a 4x4 transform (mm) as a JSON list of 4 rows")
    rot = T[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > ORTHO_TOL or np.linalg.det(rot) < 0 or \
            np.abs(T[3] - [0, 0, 0, 1]).max() > ORTHO_TOL:
        raise DataError(f"{path}: not a rigid transform (rotation block must be orthonormal with det +1, "
                        "last row 0 0 0 1)")
    return T


def detect_all(frames: Iterator[Frame], detector: TagDetector, camera: Camera, progress=None) -> list[dict]:
    """Detect tags in every frame: [{frame, corners: {id: (4, 2)}}]; size mismatches raise DataError."""
    out = []
    for frame in (progress(frames) if progress else frames):
        corners = {}
        if frame.image is not None:
            h, w = frame.image.shape[:2]
            if (w, h) != (camera.width, camera.height):
                raise DataError(f"{frame.name}: image is {w}x{h} but the camera file says "
                                f"{camera.width}x{camera.height}")
            corners = detector.detect(frame.image)
        out.append({"frame": frame, "corners": corners})
    return out


def static_global_pose(camera: Camera, detections: list[dict], tag_id: int,
                       size_mm: float) -> tuple[TagPose, np.ndarray] | None:
    """One PnP over the global tag's corners from all frames (outlier frames left out).

    Returns:
        the pose and the (4, 2) median corners (frames far from them get their own pose), or None.
    """
    quads = np.array([d["corners"][tag_id] for d in detections if tag_id in d["corners"]])
    if not len(quads):
        return None
    median = np.median(quads, axis=0)
    keep = np.abs(quads - median).max(axis=(1, 2)) <= GLOBAL_OUTLIER_PX
    first = solve_tag_pose(camera, median, size_mm)
    obj = np.tile(tag_object_points(size_mm), (int(keep.sum()), 1))
    pts = quads[keep].reshape(-1, 2)
    T = refine_pose(camera, obj, pts, first.T_cam_tag)
    if first.alternative is not None:
        alt = refine_pose(camera, obj, pts, first.alternative)
        if reprojection_rms(camera, obj, pts, alt) < reprojection_rms(camera, obj, pts, T):
            T = alt
    return TagPose(T, reprojection_rms(camera, obj, pts, T), False), median


def _pick(pose: TagPose, prev_rot: np.ndarray | None) -> np.ndarray:
    """Resolve the planar ambiguity: the best reprojection, or when ambiguous the rotation nearest the last
    one."""
    if not pose.ambiguous or pose.alternative is None or prev_rot is None:
        return pose.T_cam_tag
    d_best = rotations.rotation_angle(prev_rot.T @ pose.T_cam_tag[:3, :3])
    d_alt = rotations.rotation_angle(prev_rot.T @ pose.alternative[:3, :3])
    return pose.alternative if d_alt < d_best else pose.T_cam_tag


def _row(frame: Frame, seen: list[int], ok: bool, T_gs: np.ndarray | None = None, reproj: float | None = None,
         note: str = "") -> dict:
    pos, rv = (se3.T_to_pose(T_gs) if T_gs is not None else (np.full(3, np.nan), np.full(3, np.nan)))
    row = {"frame": frame.index, "t": frame.time_s, "position_mm": pos, "rotvec_rad": rv, "tags_seen": seen,
           "reprojection_px": reproj if reproj is not None else float("nan"), "ok": ok}
    if note:
        row["note"] = note
    return row


def solve_frames(camera: Camera, detections: list[dict], opts: TrackOptions) -> Iterator[dict]:
    """Pose rows from detections (see module docstring); frames missing a tag give ``ok: false``."""
    static = static_global_pose(camera, detections, opts.global_tag, opts.tag_size_mm) \
        if opts.global_mode == "static" else None
    obj = tag_object_points(opts.tag_size_mm)
    prev_rot = prev_global_rot = None
    for det in detections:
        frame, corners = det["frame"], det["corners"]
        seen = sorted(corners)
        if frame.image is None:
            yield _row(frame, seen, False, note=frame.note)
            continue
        missing = [name for name, tid in (("sensor", opts.sensor_tag), ("global", opts.global_tag))
                   if tid not in corners]
        if missing:
            yield _row(frame, seen, False, note=" and ".join(missing) + " tag not seen")
            continue
        g_corners = corners[opts.global_tag]
        moved = static is not None and np.abs(g_corners - static[1]).max() > GLOBAL_OUTLIER_PX
        try:
            T_cs = _pick(solve_tag_pose(camera, corners[opts.sensor_tag], opts.tag_size_mm), prev_rot)
            if static is not None and not moved:
                T_cg = static[0].T_cam_tag
            else:
                T_cg = _pick(solve_tag_pose(camera, g_corners, opts.tag_size_mm), prev_global_rot)
                prev_global_rot = T_cg[:3, :3]
        except DataError as exc:
            yield _row(frame, seen, False, note=str(exc))
            continue
        prev_rot = T_cs[:3, :3]
        errs = [reprojection_rms(camera, obj, corners[opts.sensor_tag], T_cs),
                reprojection_rms(camera, obj, g_corners, T_cg)]
        T_gs = se3.inv_T(T_cg) @ T_cs @ opts.T_stag_sensor
        yield _row(frame, seen, True, T_gs, float(np.sqrt(np.mean(np.square(errs)))),
                   note="global tag moved: solved in this frame" if moved else "")


def track(path: str, camera: Camera, opts: TrackOptions, fps: float | None = None, edge_fit: bool = True,
          progress=None) -> list[dict]:
    """Detect and solve every frame of ``path`` (folder or video); one row per frame.

    Frames that cannot be read give rows with ``ok`` false; when no frame at all can be read the
    input is not a usable recording and DataError says so.
    """
    if opts.global_tag == opts.sensor_tag:
        raise DataError(f"the sensor and global tags must differ (both are id {opts.sensor_tag})")
    if opts.tag_size_mm <= 0:
        raise DataError(f"the tag size must be positive (got {opts.tag_size_mm} mm)")
    detector = TagDetector(opts.refine, camera=camera, edge_fit=edge_fit)
    detections = detect_all(iter_frames(path, fps), detector, camera, progress)
    rows = list(solve_frames(camera, detections, opts))
    if rows and all(r.get("note") == UNREADABLE for r in rows):
        raise DataError(f"{path}: none of the {len(rows)} frames could be read as an image (corrupt or not "
                        "images)")
    return rows
