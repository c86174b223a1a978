"""The insert's phantom frame in a scan, and nearest-neighbour resampling onto the toolkit's label grid.

World coordinates are the scan's (x, y, z) mm given by its affine (array index -> world). The frame:

- axis: the insert's smallest principal direction (an octagonal prism wider than tall), pointing to
  the skin (silicone labelled insert) or, failing that, to the inclusions or the world +z;
- top: the highest slab (0.25 mm thick, along the axis) holding at least half the median slab area;
- in-plane rotation: the four flat normals of the octagon are the directions of smallest width of the
  insert's convex hull in the mid slab; of the eight normals, the one closest to the world x axis
  becomes the phantom x axis (so the rotation lies in [-22.5, 22.5) degrees and orientation 0 is the
  insert as it lies in the scan);
- centre: the midpoint between opposite flats, least squares over the four flat directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry.rotations import turn_xy
from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, LabelVolume

SLAB_MM = 0.25                  # slab thickness along the axis for the top surface
TOP_AREA_FRACTION = 0.5
MID_SLAB_FRACTION = 0.3         # half-thickness of the slab used for the outline, fraction of the height
COARSE_STEP_DEG, FINE_STEP_DEG = 0.5, 0.02
MAX_POINTS = 400_000
SAMPLE_SEED = 0
FLATS = 4                       # an octagon has four pairs of parallel flats
STEP_DEG = 45.0


@dataclass
class InsertFrame:
    """The phantom frame of an insert in world coordinates.

    Attributes:
        axes: (3, 3) columns = phantom x, y, z unit vectors in world coordinates.
        origin_mm: (3,) world position of the phantom origin (centre of the top surface).
        rotation_deg: in-plane angle of the phantom x axis from the world x axis projected on the plane.
        width_mm: measured size across flats (mean of the four).
        height_mm: measured height along the axis.
    """

    axes: np.ndarray
    origin_mm: np.ndarray
    rotation_deg: float
    width_mm: float
    height_mm: float

    def to_world(self, points_mm: np.ndarray) -> np.ndarray:
        """(n, 3) phantom x, y, z -> (n, 3) world x, y, z."""
        p = np.asarray(points_mm, dtype=np.float64)
        return (self.origin_mm + p[:, 0:1] * self.axes[:, 0] + p[:, 1:2] * self.axes[:, 1] + p[:, 2:3]
                * self.axes[:, 2])


def voxel_to_world(idx: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """(n, 3) array indices -> (n, 3) world mm."""
    a = np.asarray(affine, dtype=np.float64)
    i = np.asarray(idx, dtype=np.float64)
    return a[:3, 3] + i[:, 0:1] * a[:3, 0] + i[:, 1:2] * a[:3, 1] + i[:, 2:3] * a[:3, 2]


def _points(mask: np.ndarray, affine: np.ndarray) -> np.ndarray:
    idx = np.argwhere(mask)
    if len(idx) > MAX_POINTS:
        idx = idx[np.random.default_rng(SAMPLE_SEED).choice(len(idx), MAX_POINTS, replace=False)]
    return voxel_to_world(idx, affine)


def _axis(points: np.ndarray, up_hint: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    centre = points.mean(axis=0)
    d = points - centre
    cov = np.einsum("ni,nj->ij", d, d) / len(d)
    axis = np.linalg.eigh(cov)[1][:, 0]
    hint = np.array([0.0, 0.0, 1.0]) if up_hint is None else np.asarray(up_hint, dtype=np.float64)
    return (axis if float(axis @ hint) >= 0 else -axis), centre


def _extent(heights: np.ndarray) -> tuple[float, float]:
    """(bottom, top) along the axis from the slab areas."""
    bins = np.arange(heights.min() - SLAB_MM, heights.max() + 2 * SLAB_MM, SLAB_MM)
    counts, edges = np.histogram(heights, bins)
    full = np.flatnonzero(counts >= TOP_AREA_FRACTION * np.median(counts[counts > 0]))
    return float(edges[full[0]]), float(edges[full[-1] + 1])


def _widths(uv: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """(m,) summed widths over the four flat directions at each base angle."""
    total = np.zeros(len(angle_rad))
    for j in range(FLATS):
        a = angle_rad + math.radians(STEP_DEG * j)
        proj = np.outer(np.cos(a), uv[:, 0]) + np.outer(np.sin(a), uv[:, 1])
        total += proj.max(axis=1) - proj.min(axis=1)
    return total


def _octagon(uv: np.ndarray) -> tuple[float, np.ndarray, float]:
    """(rotation deg in [-22.5, 22.5), in-plane centre (2,), width across flats) from in-plane points."""
    from scipy.spatial import ConvexHull

    hull = uv[ConvexHull(uv).vertices]
    coarse = np.radians(np.arange(0.0, STEP_DEG, COARSE_STEP_DEG))
    best = coarse[int(np.argmin(_widths(hull, coarse)))]
    fine = best + np.radians(np.arange(-COARSE_STEP_DEG, COARSE_STEP_DEG, FINE_STEP_DEG))
    angle = float(np.degrees(fine[int(np.argmin(_widths(hull, fine)))])) % STEP_DEG
    if angle >= STEP_DEG / 2:
        angle -= STEP_DEG
    normals = np.array([[math.cos(math.radians(angle + STEP_DEG * j)),
                         math.sin(math.radians(angle + STEP_DEG * j))]
                        for j in range(FLATS)])
    proj = hull @ normals.T
    mids, widths = 0.5 * (proj.max(axis=0) + proj.min(axis=0)), proj.max(axis=0) - proj.min(axis=0)
    centre = np.linalg.lstsq(normals, mids, rcond=None)[0]
    return angle, centre, float(widths.mean())


def find_frame(labels: np.ndarray, affine: np.ndarray, up_hint: np.ndarray | None = None,
               where: str = "scan") -> InsertFrame:
    """The insert's phantom frame from a label array (any axis order) and its index->world affine.

    Args:
        labels: 3D codes; everything non-zero is the insert.
        affine: (4, 4) array index -> world x, y, z mm.
        up_hint: (3,) world vector pointing roughly from the base to the top (the skin side).
        where: name for error messages.
    """
    insert = labels != BACKGROUND
    if insert.sum() < 4 * FLATS:
        raise DataError(f"{where}: no insert to find a frame for")
    pts = _points(insert, affine)
    axis, centre = _axis(pts, up_hint)
    ref = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - (ref @ axis) * axis
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    d = pts - centre
    heights = d @ axis
    bottom, top = _extent(heights)
    mid = 0.5 * (bottom + top)
    slab = np.abs(heights - mid) <= MID_SLAB_FRACTION * (top - bottom)
    uv = np.stack([d[slab] @ e1, d[slab] @ e2], axis=1)
    angle, c_uv, width = _octagon(uv)
    a = math.radians(angle)
    ex = math.cos(a) * e1 + math.sin(a) * e2
    ey = np.cross(axis, ex)
    origin = centre + c_uv[0] * e1 + c_uv[1] * e2 + top * axis
    return InsertFrame(np.stack([ex, ey, axis], axis=1), origin, angle, width, top - bottom)


def up_hint_from(labels: np.ndarray, silicone: np.ndarray, affine: np.ndarray) -> np.ndarray | None:
    """World vector from the insert centroid to the skin (silicone labelled insert), else to the
    inclusions."""
    insert = labels != BACKGROUND
    for mask in (silicone & (labels == INSERT), labels == INCLUSION):
        if mask.sum() > 0:
            return _points(mask, affine).mean(axis=0) - _points(insert, affine).mean(axis=0)
    return None


def resample(labels: np.ndarray, affine: np.ndarray, frame: InsertFrame, shape=(26, 128, 128),
             spacing_mm=(0.9, 0.4774, 0.4774), orientation: int = 0, name: str = "") -> LabelVolume:
    """Nearest-neighbour labels on the toolkit grid in the phantom frame, geometry rotated by k * 45 deg.

    Orientation ``k`` follows :meth:`lesscli.phantom.geometry.Phantom.rotated`: the insert as found is
    orientation 0, and copy k shows its inner geometry rotated by +k * 45 degrees about z.
    """
    from lesscli.phantom.geometry import label_grid_origin

    origin = label_grid_origin(tuple(shape), tuple(spacing_mm))
    axes = [origin[a] + spacing_mm[a] * np.arange(shape[a]) for a in range(3)]
    z, y, x = np.meshgrid(*axes, indexing="ij")
    back = math.radians(-STEP_DEG * orientation)           # sample the unrotated insert at R_k^-1 q
    pts = turn_xy(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1), back)
    world = frame.to_world(pts)
    inv = np.linalg.inv(np.asarray(affine, dtype=np.float64))
    idx = np.rint(inv[:3, 3] + world[:, 0:1] * inv[:3, 0] + world[:, 1:2] * inv[:3, 1]
                  + world[:, 2:3] * inv[:3, 2]).astype(np.int64)
    inside = np.all((idx >= 0) & (idx < np.asarray(labels.shape)), axis=1)
    out = np.zeros(len(pts), dtype=np.uint8)
    out[inside] = labels[tuple(idx[inside].T)]
    return LabelVolume(out.reshape(shape), origin, spacing_mm, name)
