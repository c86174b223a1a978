"""CAD phantoms: voxelise watertight STL meshes onto the label grid by point containment.

A voxel gets a class when its centre lies inside the mesh (not when the surface touches it). Centres
are tested column by column (centres on the surface count as inside, as in ``Phantom.classify``): a vertical
line through each (x, y) column crosses the closed surface at heights z_1 < ... < z_m, and a centre is inside
when an odd number of crossings lies above it. The columns are offset by a tiny irrational amount so no line
passes exactly through a mesh edge.

Frames: with ``frame="auto"`` all meshes are shifted together so the insert's bounding box is centred
on x = y = 0 with its top at z = 0 (the phantom frame); with ``frame="phantom"`` the files are taken
to be in the phantom frame already. Units are millimetres.
"""

from __future__ import annotations

import math
import os

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry.rotations import turn_xy
from lesscli.io.labels import INCLUSION, INSERT, PILLAR, LabelVolume
from lesscli.phantom.geometry import DEFAULT_LABEL_SHAPE, DEFAULT_LABEL_SPACING_MM, label_grid_origin

COLUMN_NUDGE_MM = (3.1830988e-7, 2.7182818e-7)   # keeps column lines off mesh edges and vertices
SURFACE_EPS_MM = 1e-9                            # centres on the surface count as inside
AREA_EPS_MM2 = 1e-12                             # faces with a smaller x-y footprint are vertical
FRAMES = ("auto", "phantom")


def load_mesh(path: str):
    """A watertight trimesh from ``path`` (DataError naming the file otherwise)."""
    import trimesh

    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types on bad files
        raise DataError(f"{path}: not a readable mesh ({exc})") from None
    if len(getattr(mesh, "faces", ())) == 0:
        raise DataError(f"{path}: mesh has no faces")
    if not mesh.is_watertight:
        raise DataError(f"{path}: mesh is not watertight; close its holes before voxelising")
    return mesh


def contains_on_grid(triangles: np.ndarray, z_mm: np.ndarray, y_mm: np.ndarray,
                     x_mm: np.ndarray) -> np.ndarray:
    """Which grid points lie inside a closed triangle surface.

    Args:
        triangles: (F, 3, 3) vertex coordinates x, y, z in mm.
        z_mm, y_mm, x_mm: increasing grid coordinates along each axis (D,), (H,), (W,).

    Returns:
        (D, H, W) bool.
    """
    xs, ys = x_mm + COLUMN_NUDGE_MM[0], y_mm + COLUMN_NUDGE_MM[1]
    counter = np.zeros((len(ys), len(xs), len(z_mm) + 1), dtype=np.int32)
    for tri in triangles:
        (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = tri
        det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(det) < AREA_EPS_MM2:
            continue
        i0, i1 = np.searchsorted(ys, [min(y0, y1, y2), max(y0, y1, y2)], side="left")
        j0, j1 = np.searchsorted(xs, [min(x0, x1, x2), max(x0, x1, x2)], side="left")
        if i0 >= i1 or j0 >= j1:
            continue
        gy, gx = np.meshgrid(ys[i0:i1], xs[j0:j1], indexing="ij")
        w0 = ((y1 - y2) * (gx - x2) + (x2 - x1) * (gy - y2)) / det
        w1 = ((y2 - y0) * (gx - x2) + (x0 - x2) * (gy - y2)) / det
        w2 = 1.0 - w0 - w1
        hit = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        if not hit.any():
            continue
        zc = (w0 * z0 + w1 * z1 + w2 * z2)[hit] + math.copysign(SURFACE_EPS_MM, det)
        ii, jj = np.nonzero(hit)
        below = np.searchsorted(z_mm, zc, side="left")   # grid points under the crossing
        np.add.at(counter, (ii + i0, jj + j0, np.zeros_like(below)), 1)
        np.add.at(counter, (ii + i0, jj + j0, below), -1)
    inside = np.cumsum(counter[..., :-1], axis=-1) % 2 == 1
    return np.transpose(inside, (2, 0, 1))


def stl_label_volume(insert_path: str, inclusion_paths=(), pillar_paths=(), orientation: int = 0,
                     shape=DEFAULT_LABEL_SHAPE, spacing_mm=DEFAULT_LABEL_SPACING_MM, frame: str = "auto",
                     name: str | None = None) -> tuple[LabelVolume, dict]:
    """Label volume of an insert mesh with inclusion and pillar meshes, at orientation k.

    Returns:
        (LabelVolume, spec) where spec records the files, frame shift and grid (JSON-ready).
    """
    if frame not in FRAMES:
        raise DataError(f"unknown STL frame '{frame}' (choose {', '.join(FRAMES)})")
    meshes = {"insert": [load_mesh(insert_path)], "inclusion": [load_mesh(p) for p in inclusion_paths],
              "pillar": [load_mesh(p) for p in pillar_paths]}
    lo, hi = meshes["insert"][0].bounds
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -hi[2]]) if frame == "auto" else np.zeros(3)
    origin = label_grid_origin(shape, spacing_mm)
    axes = [origin[a] + spacing_mm[a] * np.arange(shape[a]) for a in range(3)]
    data = np.zeros(shape, dtype=np.uint8)
    for key, code in (("insert", INSERT), ("pillar", PILLAR), ("inclusion", INCLUSION)):
        for mesh in meshes[key]:
            verts = turn_xy(np.asarray(mesh.vertices, dtype=np.float64) + shift, orientation * math.pi / 4)
            data[contains_on_grid(verts[np.asarray(mesh.faces)], *axes)] = code
    base = name or os.path.splitext(os.path.basename(insert_path))[0]
    spec = {"schema": "less.phantom-stl", "version": 1, "name": base, "orientation": int(orientation) % 8,
            "insert": os.path.abspath(insert_path),
            "inclusions": [os.path.abspath(p) for p in inclusion_paths],
            "pillars": [os.path.abspath(p) for p in pillar_paths], "frame": frame,
            "shift_mm": shift.round(9).tolist(), "width_mm": float(hi[0] - lo[0]),
            "height_mm": float(hi[2] - lo[2])}
    return LabelVolume(data, origin, spacing_mm, f"{base}_{int(orientation) % 8}"), spec
