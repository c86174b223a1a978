"""Per-class surfaces of a label volume, in phantom-frame millimetres.

Each class mask is padded by one empty voxel (so every surface closes), meshed by marching cubes at
level 0.5 with the voxel spacing, moved to the phantom frame (x, y, z mm, z up), cleaned and smoothed
with trimesh (Taubin smoothing keeps the volume), optionally decimated and repaired with pymeshlab,
and oriented so the normals point outward (positive signed volume). A GLB is written in glTF's own
frame (metres, +Y up); STL and PLY, which carry no unit, in the phantom frame's millimetres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.io.labels import CLASS_NAMES, LabelVolume
from lesscli.plots.palette import CLASS_RGBA

MC_LEVEL = 0.5              # iso-level between an empty (0) and a full (1) voxel
TAUBIN_LAMBDA, TAUBIN_NU = 0.5, 0.53   # shrink by lambda, then inflate by nu (trimesh negates nu)
MESH_FORMATS = {".glb": "glb", ".stl": "stl", ".ply": "ply"}


@dataclass
class ClassMesh:
    """One class's surface. ``mesh`` is a ``trimesh.Trimesh`` with vertices in x, y, z mm."""

    code: int
    name: str
    mesh: object

    def record(self) -> dict:
        m = self.mesh
        return {"class": self.name, "code": self.code, "vertices": len(m.vertices),
                "faces": len(m.faces), "volume_mm3": float(m.volume), "area_mm2": float(m.area),
                "watertight": bool(m.is_watertight)}


def class_surface(volume: LabelVolume, code: int, smooth_iterations: int = 10,
                  target_faces: int | None = None):
    """Surface of ``volume.data == code`` as a ``trimesh.Trimesh`` (None when the class is empty).

    Args:
        volume: label volume (D, H, W) with geometry.
        code: class code.
        smooth_iterations: Taubin smoothing passes (0 = none).
        target_faces: decimate to about this many faces with pymeshlab (None = keep).
    """
    import trimesh
    from skimage.measure import marching_cubes

    mask = volume.data == code
    if not mask.any():
        return None
    padded = np.pad(mask, 1).astype(np.float32)
    verts_zyx, faces, _, _ = marching_cubes(padded, level=MC_LEVEL, spacing=tuple(volume.spacing_mm))
    verts_zyx = verts_zyx + (volume.origin_mm - volume.spacing_mm)    # undo the one-voxel pad
    mesh = trimesh.Trimesh(vertices=verts_zyx[:, ::-1].copy(), faces=faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if smooth_iterations > 0:
        trimesh.smoothing.filter_taubin(mesh, lamb=TAUBIN_LAMBDA, nu=TAUBIN_NU, iterations=smooth_iterations)
    if target_faces is not None and len(mesh.faces) > target_faces:
        mesh = decimate(mesh, target_faces)
    trimesh.repair.fix_normals(mesh, multibody=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def decimate(mesh, target_faces: int):
    """Quadric edge-collapse decimation and non-manifold repair with pymeshlab."""
    import pymeshlab
    import trimesh

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(mesh.vertices, np.float64),
                               face_matrix=np.asarray(mesh.faces, np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces), preservetopology=True,
                                                preservenormal=True, qualitythr=0.5)
    ms.meshing_repair_non_manifold_edges()
    ms.meshing_remove_unreferenced_vertices()
    out = ms.current_mesh()
    return trimesh.Trimesh(vertices=out.vertex_matrix(), faces=out.face_matrix(), process=True)


def label_meshes(volume: LabelVolume, codes: tuple[int, ...] = (1, 2, 3), smooth_iterations: int = 10,
                 target_faces: int | None = None) -> list[ClassMesh]:
    """Surfaces of the given classes that occur in ``volume``, coloured by the class palette."""
    out = []
    for code in codes:
        mesh = class_surface(volume, code, smooth_iterations, target_faces)
        if mesh is None:
            continue
        mesh.visual.face_colors = (CLASS_RGBA[code] * 255).astype(np.uint8)
        out.append(ClassMesh(code, CLASS_NAMES[code], mesh))
    return out


def mesh_format(path: str) -> str:
    """'glb' | 'stl' | 'ply' from the output name's extension."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_FORMATS:
        raise DataError(f"{path}: unknown mesh format '{ext}', expected one of {', '.join(MESH_FORMATS)}")
    return MESH_FORMATS[ext]


# glTF's frame: metres, +Y up. Phantom frame (mm, +Z up) -> glTF: x -> x, z -> y, y -> -z, times 1e-3
# (a proper rotation, so the normals stay outward). STL and PLY carry no unit: they stay in mm, z up.
GLTF_FROM_PHANTOM = np.array([[1e-3, 0, 0, 0], [0, 0, 1e-3, 0], [0, -1e-3, 0, 0], [0, 0, 0, 1]])


def export_meshes(meshes: list[ClassMesh], path: str, fmt: str) -> None:
    """Write meshes to ``path`` (the caller makes it atomic): GLB as a scene with one named node per class, in
    glTF's metres
    with +Y up (:data:`GLTF_FROM_PHANTOM`: a 60 mm phantom opens 0.06 m wide); STL/PLY as one mesh in mm."""
    import trimesh

    if not meshes:
        raise DataError(f"{path}: nothing to mesh (none of the requested classes occurs in the volume)")
    if fmt == "glb":
        scene = trimesh.Scene()
        for m in meshes:
            scene.add_geometry(m.mesh.copy().apply_transform(GLTF_FROM_PHANTOM), node_name=m.name,
                               geom_name=m.name)
        data = scene.export(file_type="glb")
    else:
        data = trimesh.util.concatenate([m.mesh for m in meshes]).export(file_type=fmt)
    with open(path, "wb") as fh:
        fh.write(data if isinstance(data, bytes) else data.encode())
