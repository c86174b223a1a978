"""AprilTag (36h11) detection with OpenCV's ``cv2.aruco`` and per-tag pose by PnP.

Marker frame (OpenCV's convention): origin at the tag centre, x right, y up, z out of the tag, in mm.
Corners come in the detector's order: top-left, top-right, bottom-right, bottom-left as the tag is
read, i.e. tag-frame points (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2) for a black square of
side s. Pixel centres sit at integer coordinates.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from lesscli.errors import DataError
from lesscli.geometry import rotations
from lesscli.vision import se3
from lesscli.vision.camera import Camera
from lesscli.vision.edges import refine_corners

# Added to the corners from CORNER_REFINE_APRILTAG (px, both axes): they come out about half a pixel too far
# right and down against the pixel-centre convention (measured on renders with exactly known corners, see
# tests/vision/test_vision_detect.py; the other refinements show no such offset).
APRILTAG_CORNER_OFFSET_PX = -0.5
# second IPPE solution within this factor of the best reprojection error: ambiguous
AMBIGUITY_RATIO = 2.0
REFINE_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


@functools.cache
def DICTIONARY():
    """OpenCV's AprilTag 36h11 dictionary."""
    return cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)


def marker_cells() -> int:
    """Cells per tag side including the one-cell black border (8 for 36h11)."""
    return int(DICTIONARY().markerSize) + 2


def _refine_apriltag(params) -> None:
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG


def _refine_subpix(params) -> None:
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    params.cornerRefinementMaxIterations = 50
    params.cornerRefinementMinAccuracy = 0.005


def _refine_none(params) -> None:
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE


# name -> (parameter setup, corner offset to add, px)
REFINERS: dict[str, tuple] = {
    "apriltag": (_refine_apriltag, APRILTAG_CORNER_OFFSET_PX),
    "subpix": (_refine_subpix, 0.0),
    "none": (_refine_none, 0.0),
}


class TagDetector:
    """Find 36h11 tags in greyscale frames; corners are corrected to the pixel-centre convention.

    Args:
        refine: the detector's corner refinement, a key of REFINERS.
        corner_offset_px: override the refinement's half-pixel correction (None: the measured default).
        camera: needed for ``edge_fit`` (edge points are undistorted before the line fit).
        edge_fit: refine the corners further by fitting lines to the tag's outer edges (lesscli.vision.edges).
    """

    def __init__(self, refine: str = "apriltag", corner_offset_px: float | None = None,
                 camera: Camera | None = None, edge_fit: bool = True) -> None:
        if refine not in REFINERS:
            raise DataError(f"unknown corner refinement '{refine}' (choose from {', '.join(REFINERS)})")
        setup, offset = REFINERS[refine]
        params = cv2.aruco.DetectorParameters()
        setup(params)
        self.refine = refine
        self.offset_px = offset if corner_offset_px is None else float(corner_offset_px)
        self._detector = cv2.aruco.ArucoDetector(DICTIONARY(), params)
        self.camera = camera
        self.edge_fit = edge_fit and camera is not None

    def detect(self, gray: np.ndarray) -> dict[int, np.ndarray]:
        """Tags in one frame.

        Args:
            gray: (H, W) uint8 image (a colour (H, W, 3) BGR image is converted).

        Returns:
            tag id -> (4, 2) float64 corners, px (top-left, top-right, bottom-right, bottom-left).
            A tag id seen twice is dropped (it cannot be told apart).
        """
        if gray.ndim == 3:
            gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return {}
        ids = ids.ravel().tolist()
        found = {}
        for tag_id, quad in zip(ids, corners):
            if ids.count(tag_id) == 1:
                quad = quad.reshape(4, 2).astype(np.float64) + self.offset_px
                if self.edge_fit:
                    quad = refine_corners(gray, quad, self.camera.matrix, self.camera.dist_coeffs,
                                          marker_cells())
                found[int(tag_id)] = quad
        return found


def tag_object_points(tag_size_mm: float) -> np.ndarray:
    """(4, 3) corners in the marker frame, in the detector's corner order, mm."""
    h = tag_size_mm / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass
class TagPose:
    """``T_cam_tag`` (4, 4, mm), its RMS reprojection error (px), and whether IPPE's two solutions were
    close."""

    T_cam_tag: np.ndarray
    reprojection_px: float
    ambiguous: bool
    alternative: np.ndarray | None = None


def reprojection_rms(camera: Camera, object_mm: np.ndarray, image_px: np.ndarray, T: np.ndarray) -> float:
    """RMS pixel distance between ``image_px`` (n, 2) and the projections of ``object_mm`` (n, 3) under T."""
    rvec = rotations.matrix_to_rotvec(T[:3, :3])
    proj, _ = cv2.projectPoints(object_mm.reshape(-1, 1, 3), rvec, T[:3, 3], camera.matrix,
                                camera.dist_coeffs)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - image_px) ** 2, axis=1))))


def refine_pose(camera: Camera, object_mm: np.ndarray, image_px: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt refinement of ``T`` (4, 4) minimising the reprojection error."""
    rvec = rotations.matrix_to_rotvec(T[:3, :3]).reshape(3, 1).copy()
    tvec = T[:3, 3].reshape(3, 1).copy()
    rvec, tvec = cv2.solvePnPRefineLM(object_mm.reshape(-1, 1, 3), image_px.reshape(-1, 1, 2), camera.matrix,
                                      camera.dist_coeffs, rvec, tvec, criteria=REFINE_CRITERIA)
    return se3.make_T(rotations.rotvec_to_matrix(rvec.ravel()), tvec.ravel())


def solve_tag_pose(camera: Camera, corners_px: np.ndarray, tag_size_mm: float) -> TagPose:
    """Pose of one square tag from its 4 corners: IPPE_SQUARE's two solutions, each LM-refined.

    The planar ambiguity: IPPE returns both local minima; the one with the lower reprojection error wins,
    and when the two are within ``AMBIGUITY_RATIO`` the pose is flagged ``ambiguous`` and the other
    solution kept in ``alternative`` so that a caller can decide by consistency (previous frame).

    Args:
        camera: intrinsics.
        corners_px: (4, 2) corners in the detector's order.
        tag_size_mm: side of the black square.
    """
    obj = tag_object_points(tag_size_mm)
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj.reshape(-1, 1, 3), corners_px.reshape(-1, 1, 2),
                                             camera.matrix, camera.dist_coeffs,
                                             flags=cv2.SOLVEPNP_IPPE_SQUARE)
    cands = []
    for rvec, tvec in zip(rvecs[:n], tvecs[:n]):
        T = refine_pose(camera, obj, corners_px,
                        se3.make_T(rotations.rotvec_to_matrix(rvec.ravel()), tvec.ravel()))
        if T[2, 3] > 0:
            cands.append((reprojection_rms(camera, obj, corners_px, T), T))
    if not cands:
        raise DataError("tag pose: no solution in front of the camera")
    cands.sort(key=lambda c: c[0])
    best_err, best = cands[0]
    if len(cands) == 1:
        return TagPose(best, best_err, False)
    other_err, other = cands[1]
    ambiguous = other_err < AMBIGUITY_RATIO * max(best_err, 1e-3)
    return TagPose(best, best_err, ambiguous, other)
