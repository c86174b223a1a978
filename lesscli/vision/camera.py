"""Pinhole camera with OpenCV's 5-term distortion, read from and written to ``cam.json``.

``cam.json`` holds ``{"fx", "fy", "cx", "cy", "width", "height", "dist": [k1, k2, p1, p2, k3]}`` with
focal lengths and principal point in pixels. Pixel centres sit at integer coordinates (OpenCV).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError

CAMERA_KEYS = ("fx", "fy", "cx", "cy", "width", "height")


@dataclass(frozen=True)
class Camera:
    """Intrinsics in pixels; ``dist`` = (k1, k2, p1, p2, k3)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """(5,) distortion coefficients for OpenCV."""
        return np.asarray(self.dist, np.float64)

    def to_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "width": self.width,
                "height": self.height, "dist": list(self.dist)}


def default_camera() -> Camera:
    """A 1280x720 camera with f = 900 px and mild radial distortion (a RealSense-like IR imager)."""
    return Camera(900.0, 900.0, 639.5, 359.5, 1280, 720, (0.02, -0.05, 0.0, 0.0, 0.0))


def camera_from_dict(data: object, name: str) -> Camera:
    """Validate a parsed ``cam.json``; raises DataError naming the file and the bad key."""
    if not isinstance(data, dict):
        raise DataError(f"{name}: camera file must hold a JSON object with keys {', '.join(CAMERA_KEYS)}, "
                        "dist")
    missing = [k for k in CAMERA_KEYS if k not in data]
    if missing:
        raise DataError(f"{name}: camera file lacks {', '.join(repr(k) for k in missing)} "
                        f"(expected {', '.join(CAMERA_KEYS)}, dist)")
    try:
        vals = {k: float(data[k]) for k in CAMERA_KEYS}
        dist = tuple(float(v) for v in data.get("dist", [0.0] * 5))
    except (TypeError, ValueError):
        raise DataError(f"{name}: camera values must be numbers") from None
    if not all(math.isfinite(v) for v in (*vals.values(), *dist)):
        raise DataError(f"{name}: camera values must be finite")
    if vals["fx"] <= 0 or vals["fy"] <= 0:
        raise DataError(f"{name}: focal lengths fx, fy must be positive (got {vals['fx']}, {vals['fy']})")
    if (vals["width"] < 1 or vals["height"] < 1 or not vals["width"].is_integer()
        or not vals["height"].is_integer()):
        raise DataError(f"{name}: width and height must be positive integers")
    if len(dist) not in (4, 5):
        raise DataError(f"{name}: 'dist' must hold [k1, k2, p1, p2, k3] (got {len(dist)} values)")
    dist = dist + (0.0,) * (5 - len(dist))
    return Camera(vals["fx"], vals["fy"], vals["cx"], vals["cy"], int(vals["width"]), int(vals["height"]),
                  dist)


def load_camera(path: str) -> Camera:
    """Read ``cam.json``; a missing file, bad JSON or bad values raise one-line DataErrors."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise DataError(f"{path}: no such camera file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: camera file is not valid JSON ({exc})") from None
    return camera_from_dict(data, path)


def save_camera(path: str, camera: Camera) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(camera.to_dict(), fh, indent=1)
        fh.write("\n")
