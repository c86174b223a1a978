"""Sub-pixel corner refinement by fitting lines to a tag's four outer edges.

The detector's corners (both OpenCV refinements) are good to a few tenths of a pixel; a tag's outer
edge, black border against the white quiet zone, is a long straight step that pins the corners far
better. For each edge, intensity profiles are sampled across it (bilinear), the step's position
(by the area under the normalised profile) gives one edge point per pixel of edge length, the points are
undistorted (so lines stay straight under lens distortion), a total-least-squares line is fitted with outlier
rejection, and neighbouring lines intersect in the corners, which are distorted back to pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from lesscli.robust import robust_sigma

PROFILE_STEP_PX = 0.25      # sampling step along each profile
EDGE_MARGIN = 0.15          # fraction of the edge left out at each end (corners blur both edges)
MAX_HALF_WIDTH_PX = 3.0     # profiles reach this far each side of the edge (capped by a fraction of a cell)
CELL_FRACTION = 0.8         # ... of one tag cell, so a profile never reaches the data bits
MIN_CONTRAST = 12.0         # grey levels between the dark and bright plateaus for a usable profile
MIN_POINTS = 6              # edge points needed to fit a line
OUTLIER_SIGMAS = 3.0        # residuals beyond this many robust sigmas are dropped before the final fit
EDGE_PASSES = 2             # refinement passes (see refine_corners)
MAX_SHIFT_PX = 1.5          # a refined corner moving farther than this is distrusted (detector kept)
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)


def _sample(gray: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of float32 ``gray`` at (..., 2) pixel coordinates (x, y)."""
    shape = pts.shape[:-1]
    flat = pts.reshape(-1, 2).astype(np.float32)
    out = cv2.remap(gray, flat[:, :1].copy(), flat[:, 1:].copy(), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(shape)


def _edge_points(gray: np.ndarray, a: np.ndarray, b: np.ndarray, outward: np.ndarray,
                 half_px: float) -> np.ndarray:
    """Sub-pixel points (n, 2) on the dark-to-bright step between corners ``a`` and ``b``."""
    length = float(np.linalg.norm(b - a))
    n = max(int(length * (1 - 2 * EDGE_MARGIN)), 2)
    s = np.linspace(EDGE_MARGIN, 1 - EDGE_MARGIN, n)
    base = a[None, :] + s[:, None] * (b - a)[None, :]
    offs = np.arange(-half_px, half_px + 1e-9, PROFILE_STEP_PX)
    prof = _sample(gray, base[:, None, :] + offs[None, :, None] * outward[None, None, :])
    k = max(round(1.0 / PROFILE_STEP_PX), 1)
    dark, bright = prof[:, :k].mean(axis=1), prof[:, -k:].mean(axis=1)
    good = bright - dark > MIN_CONTRAST
    # Area method: the integral of the normalised profile is the length of its bright part, so the step
    # sits at (profile end - integral). Unlike a mid-level crossing between interpolated samples it does
    # not depend on where the edge falls between pixel centres, and any symmetric blur leaves it unbiased.
    norm = (prof - dark[:, None]) / np.where(good, bright - dark, 1.0)[:, None]
    area = PROFILE_STEP_PX * (norm.sum(axis=1) - 0.5 * (norm[:, 0] + norm[:, -1]))
    d = offs[-1] - area
    good &= np.abs(d) < half_px
    return (base + d[:, None] * outward[None, :])[good]


def _fit_line(pts: np.ndarray) -> np.ndarray | None:
    """Total-least-squares line (a, b, c) with a x + b y + c = 0, |(a, b)| = 1; robust to outliers."""
    keep = np.ones(len(pts), bool)
    for _ in range(2):
        if keep.sum() < MIN_POINTS:
            return None
        centre = pts[keep].mean(axis=0)
        _, _, vt = np.linalg.svd(pts[keep] - centre)
        normal = vt[1]
        line = np.array([normal[0], normal[1], -normal @ centre])
        resid = pts @ line[:2] + line[2]
        mad = robust_sigma(resid[keep])
        keep = np.abs(resid) <= OUTLIER_SIGMAS * max(mad, 1e-9)
    return line


def refine_corners(gray: np.ndarray, corners_px: np.ndarray, camera_matrix: np.ndarray,
                   dist_coeffs: np.ndarray, cells: int = 8, passes: int = EDGE_PASSES) -> np.ndarray:
    """Refine a tag's 4 corners (detector order) from its outer edges.

    Args:
        gray: (H, W) uint8 image.
        corners_px: (4, 2) corners, px (top-left, top-right, bottom-right, bottom-left).
        camera_matrix: (3, 3) K.
        dist_coeffs: (5,) distortion.
        cells: cells per tag side (the profile width stays inside the border cell).
        passes: refinement passes; later passes centre the profiles on the edges found before, so the
            plateau samples at both ends sit equally far from the step.

    Returns:
        (4, 2) refined corners; the input corners where an edge could not be fitted.
    """
    start = np.asarray(corners_px, np.float64)
    corners = start
    for _ in range(passes):
        refined = _refine_once(gray, corners, camera_matrix, dist_coeffs, cells)
        if refined is None or np.any(np.linalg.norm(refined - start, axis=1) > MAX_SHIFT_PX):
            return corners
        corners = refined
    return corners


def _refine_once(gray: np.ndarray, corners: np.ndarray, camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                 cells: int) -> np.ndarray | None:
    """One pass of :func:`refine_corners`; None when an edge cannot be fitted."""
    # work on a float crop around the tag (sampling the whole frame per edge would be wasteful)
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int) - 8, 0)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int) + 9
    crop = gray[y0:y1, x0:x1].astype(np.float32)
    offset = np.array([x0, y0], np.float64)
    centre = corners.mean(axis=0)
    side_px = np.mean(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1))
    half = min(MAX_HALF_WIDTH_PX, CELL_FRACTION * side_px / cells)
    lines = []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        direction = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        outward = np.array([direction[1], -direction[0]])
        if outward @ ((a + b) / 2 - centre) < 0:
            outward = -outward
        pts = _edge_points(crop, a - offset, b - offset, outward, half) + offset
        if len(pts) < MIN_POINTS:
            return None
        norm = cv2.undistortPoints(pts.reshape(-1, 1, 2), camera_matrix, dist_coeffs,
                                   criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
        line = _fit_line(norm)
        if line is None:
            return None
        lines.append(line)
    # corner k lies on edges k-1 (from corner k-1 to k) and k (from corner k to k+1)
    hom = np.array([np.cross(lines[k - 1], lines[k]) for k in range(4)])
    if np.any(np.abs(hom[:, 2]) < 1e-12):
        return None
    norm_corners = np.concatenate([hom[:, :2] / hom[:, 2:], np.ones((4, 1))], axis=1)
    refined, _ = cv2.projectPoints(norm_corners.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera_matrix,
                                   dist_coeffs)
    return refined.reshape(4, 2)
