"""Records about a segmentation (class volumes, inclusions, base surface, pillars, frame, warnings) and a QC
figure."""

from __future__ import annotations

import math

import numpy as np

from lesscli.io.labels import BACKGROUND, CLASS_NAMES, INCLUSION, INSERT, PILLAR

OVERLAY_RGBA = {INSERT: (0.2, 0.5, 1.0, 0.25), INCLUSION: (1.0, 0.1, 0.1, 0.6)}
OUTLINE_RGB = (1.0, 0.6, 0.0)           # pillar outline
QC_DPI = 90


def class_rows(labels: np.ndarray, affine: np.ndarray) -> list[dict]:
    """One row per class: voxel count and volume in mm^3 (|det| of the affine per voxel)."""
    voxel_mm3 = abs(float(np.linalg.det(np.asarray(affine)[:3, :3])))
    counts = np.bincount(labels.ravel(), minlength=len(CLASS_NAMES))
    return [{"row": "class", "class": name, "voxels": int(counts[c]),
             "volume_mm3": float(counts[c]) * voxel_mm3}
            for c, name in enumerate(CLASS_NAMES)]


def inclusion_rows(labels: np.ndarray, affine: np.ndarray) -> list[dict]:
    """One row per inclusion (largest first): volume, equivalent-sphere and longest diameters, centroid.

    Centroids are world x, y, z mm of the affine's frame; ``extent_mm`` is the largest distance between
    two voxel centres of the inclusion (a lower bound of its size by up to one voxel).
    """
    from scipy import ndimage
    from scipy.spatial import ConvexHull, QhullError

    from lesscli.mri.frame import voxel_to_world

    comps, _n = ndimage.label(labels == INCLUSION)
    voxel_mm3 = abs(float(np.linalg.det(np.asarray(affine)[:3, :3])))
    rows = []
    for i, sl in enumerate(ndimage.find_objects(comps), start=1):
        idx = np.argwhere(comps[sl] == i) + [s.start for s in sl]
        pts = voxel_to_world(idx, affine)
        try:
            hull = pts[ConvexHull(pts).vertices] if len(pts) >= 5 else pts
        except QhullError:
            hull = pts
        diff = hull[:, None, :] - hull[None, :, :]
        volume = len(idx) * voxel_mm3
        rows.append({"row": "inclusion", "volume_mm3": volume,
                     "diameter_mm": (6.0 * volume / math.pi) ** (1.0 / 3.0),
                     "extent_mm": float(np.sqrt((diff ** 2).sum(axis=2)).max()),
                     "centroid_mm": [round(float(v), 3) for v in pts.mean(axis=0)]})
    rows.sort(key=lambda r: -r["volume_mm3"])
    for k, row in enumerate(rows):
        row["index"] = k
    return rows


def shape_rows(shapes: list[dict], affine: np.ndarray) -> list[dict]:
    """One row per inclusion on how its surface was drawn (``mri-label --inclusion-shape``): its fitted
    ball's or body's centre (world x, y, z mm of the scan's affine), the ball's diameter and misfit."""
    from lesscli.mri.frame import voxel_to_world

    return [{"row": "inclusion_shape", "shape": s["shape"],
             "centre_mm": [round(float(v), 3)
                           for v in voxel_to_world(np.asarray([s["centre_index"]]), affine)[0]],
             "ball_diameter_mm": s["ball_diameter_mm"], "ball_misfit": s["ball_misfit"]} for s in shapes]


def _world_mm(point_mm: np.ndarray, spacing: np.ndarray, affine: np.ndarray) -> list[float]:
    """A point in array-axis millimetres (index times spacing) in the affine's world frame, rounded."""
    from lesscli.mri.frame import voxel_to_world

    return [round(float(v), 3) for v in voxel_to_world(np.asarray(point_mm)[None] / spacing, affine)[0]]


def base_rows(base, spacing_mm, shape: tuple, affine: np.ndarray) -> list[dict]:
    """The base's surface under the filling (:class:`lesscli.mri.pillar.BaseSurface`, found under the
    pillars; no row without one) in the affine's world frame: the plane's point nearest the scan's centre
    and its unit normal, pointing into the base."""
    if base is None:
        return []
    spacing = np.asarray(spacing_mm, dtype=np.float64)
    centre = (np.asarray(shape) - 1) / 2 * spacing
    point = centre - (float(base.normal @ centre) - base.offset_mm) * base.normal
    normal = np.linalg.solve(np.asarray(affine)[:3, :3].T, base.normal * spacing)
    return [{"row": "base_surface", "point_mm": _world_mm(point, spacing, affine),
             "normal": [round(float(v), 5) for v in normal / np.linalg.norm(normal)]}]


def post_rows(posts: list, spacing_mm, affine: np.ndarray) -> list[dict]:
    """One row per pillar drawn (:class:`lesscli.mri.pillar.Post`) in the affine's world frame: its foot
    (the centre of its end on the base), the unit direction up its axis, its diameter and its height from
    the base's surface to its inclusion's along the insert axis (and ``measured_diameter_mm``, as the scan
    measured it, where the diameter drawn was given)."""
    spacing = np.asarray(spacing_mm, dtype=np.float64)
    rows = []
    for post in posts:
        up = np.asarray(affine)[:3, :3] @ (post.direction / spacing)
        rows.append({"row": "pillar", "foot_mm": _world_mm(post.foot_mm, spacing, affine),
                     "direction": [round(float(v), 5) for v in up / np.linalg.norm(up)],
                     "diameter_mm": round(2.0 * post.radius_mm, 3), "height_mm": round(post.height_mm, 3)}
                    | ({} if post.measured_radius_mm is None
                       else {"measured_diameter_mm": round(2.0 * post.measured_radius_mm, 3)}))
    return rows


def frame_row(frame) -> dict:
    """The found phantom frame as a record."""
    return {"row": "frame", "rotation_deg": frame.rotation_deg, "width_mm": frame.width_mm,
            "height_mm": frame.height_mm, "origin_mm": [round(float(v), 3) for v in frame.origin_mm],
            "axis": [round(float(v), 5) for v in frame.axes[:, 2]]}


def warning_rows(warnings: list[str]) -> list[dict]:
    return [{"row": "warning", "message": w} for w in warnings]


def _overlay(labels2d: np.ndarray) -> np.ndarray:
    """RGBA fill of insert and inclusion (the pillar is outlined, not filled, so its intensity shows)."""
    rgba = np.zeros(labels2d.shape + (4,))
    for code, colour in OVERLAY_RGBA.items():
        rgba[labels2d == code] = colour
    return rgba


def qc_centres(labels: np.ndarray) -> list[np.ndarray]:
    """Voxel centres the QC planes pass through: each inclusion (largest first), else the insert's centre."""
    from scipy import ndimage

    comps, n = ndimage.label(labels == INCLUSION)
    if n:
        sizes = ndimage.sum_labels(np.ones(labels.shape), comps, np.arange(1, n + 1))
        order = np.argsort(-np.asarray(sizes)) + 1
        return [np.round(ndimage.center_of_mass(comps == i)).astype(int) for i in order]
    body = labels != BACKGROUND
    return [np.round(np.argwhere(body).mean(axis=0)).astype(int) if body.any()
            else np.array(labels.shape) // 2]


def save_qc(path: str, image: np.ndarray, labels: np.ndarray, spacing_mm, title: str = "") -> None:
    """PNG: for each inclusion a row of the three orthogonal planes through its centre, labels overlaid
    (insert blue, inclusion red) and the pillar outlined in orange.

    Args:
        path: output .png (written atomically).
        image: 3D intensities; labels: same shape codes; spacing_mm: (3,) per array axis.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lesscli.io.atomic import atomic_path

    spacing = np.asarray(spacing_mm, dtype=np.float64)
    lo, hi = np.percentile(image, [1, 99.5])
    centres = qc_centres(labels)
    fig, axes = plt.subplots(len(centres), 3, figsize=(12, 4.2 * len(centres)), squeeze=False)
    for row, centre in enumerate(centres):
        for axis in range(3):
            ax, keep = axes[row, axis], [a for a in range(3) if a != axis]
            img2d, lab2d = np.take(image, centre[axis], axis=axis), np.take(labels, centre[axis], axis=axis)
            h_mm, w_mm = img2d.shape[0] * spacing[keep[0]], img2d.shape[1] * spacing[keep[1]]
            extent = (0, w_mm, h_mm, 0)
            ax.imshow(img2d, cmap="gray", vmin=lo, vmax=hi, extent=extent, interpolation="nearest")
            ax.imshow(_overlay(lab2d), extent=extent, interpolation="nearest")
            pillar = (lab2d == PILLAR).astype(float)
            if pillar.any():
                xs = (np.arange(img2d.shape[1]) + 0.5) * spacing[keep[1]]
                ys = (np.arange(img2d.shape[0]) + 0.5) * spacing[keep[0]]
                ax.contour(xs, ys, pillar, levels=[0.5], colors=[OUTLINE_RGB], linewidths=1.2)
            name = f"inclusion {row}" if (labels == INCLUSION).any() else "insert"
            ax.set_title(f"{name}: axis {axis} = {centre[axis]}")
            ax.set_xlabel(f"axis {keep[1]} (mm)")
            ax.set_ylabel(f"axis {keep[0]} (mm)")
    fig.suptitle(title or "labels: blue insert, orange outline pillar, red inclusion")
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=QC_DPI)
    plt.close(fig)
