"""Write phantom label volumes (NIfTI) and geometry specs (JSON) into a folder, atomically."""

from __future__ import annotations

import json
import os

import numpy as np

from lesscli.errors import DataError, did_you_mean
from lesscli.io.atomic import atomic_dir
from lesscli.io.labels import CLASS_NAMES, LabelVolume, save_nifti
from lesscli.phantom.catalogue import resolve_set
from lesscli.phantom.geometry import Phantom, default_label_spacing


def _record(volume: LabelVolume, insert: str, k: int, nifti: str, spec: str) -> dict:
    counts = np.bincount(volume.data.ravel(), minlength=len(CLASS_NAMES))
    return {"insert": insert, "orientation": k, "nifti": nifti, "spec": spec, "shape": list(volume.shape),
            "spacing_mm": volume.spacing_mm.tolist(),
            **{f"{name}_voxels": int(c) for name, c in zip(CLASS_NAMES[1:], counts[1:])}}


def _grid_dict(volume: LabelVolume, nifti: str) -> dict:
    return {"file": nifti, "shape": list(volume.shape), "origin_mm": volume.origin_mm.tolist(),
            "spacing_mm": volume.spacing_mm.tolist()}


def select(phantoms: list[Phantom], names: list[str] | None, limit: int | None, where: str) -> list[Phantom]:
    """The named inserts (in the given order) and/or the first ``limit`` of them."""
    if names:
        known = {p.name: p for p in phantoms}
        for name in names:
            if name not in known:
                raise DataError(f"{where}: no insert '{name}'{did_you_mean(name, known)}")
        phantoms = [known[n] for n in names]
    return phantoms[:limit] if limit else phantoms


def write_set(out_dir: str, set_name: str, orientations, shape, spacing_mm, limit=None, names=None,
              phantoms: list[Phantom] | None = None) -> list[dict]:
    """Labels and specs for a catalogue or phantom file (or the given ``phantoms``, ``set_name`` then
    naming their source, e.g. ``random``); returns one record per volume."""
    phantoms = select(resolve_set(set_name) if phantoms is None else phantoms, names, limit, set_name)
    rows = []
    with atomic_dir(out_dir) as tmp:
        for base in phantoms:
            step = spacing_mm or default_label_spacing(base.width_mm)
            for k in orientations:
                phantom = base.rotated(k)
                volume = phantom.label_volume(tuple(shape), tuple(step))
                stem = f"{phantom.name}_{k}"
                save_nifti(os.path.join(tmp, stem + ".nii.gz"), volume)
                spec = {**phantom.to_dict(), "label": _grid_dict(volume, stem + ".nii.gz")}
                with open(os.path.join(tmp, stem + ".json"), "w") as fh:
                    json.dump(spec, fh, indent=1)
                rows.append(_record(volume, phantom.name, k, os.path.join(out_dir, stem + ".nii.gz"),
                                    os.path.join(out_dir, stem + ".json")))
        with open(os.path.join(tmp, "phantoms.json"), "w") as fh:
            json.dump({"schema": "less.phantom-set", "version": 1, "source": set_name,
                       "phantoms": [p.rotated(0).to_dict() for p in phantoms]}, fh, indent=1)
    return rows


def write_stl(out_dir: str, insert_path: str, inclusion_paths, pillar_paths, orientations, shape, spacing_mm,
              frame: str = "auto", name: str | None = None) -> list[dict]:
    """Voxelise STL meshes per orientation; returns one record per volume."""
    from lesscli.phantom.stl import load_mesh, stl_label_volume

    width = float(np.ptp(load_mesh(insert_path).bounds[:, 0]))
    step = spacing_mm or default_label_spacing(width)
    rows = []
    with atomic_dir(out_dir) as tmp:
        for k in orientations:
            volume, spec = stl_label_volume(insert_path, inclusion_paths, pillar_paths, k, tuple(shape),
                                            tuple(step), frame, name)
            stem = volume.name
            save_nifti(os.path.join(tmp, stem + ".nii.gz"), volume)
            with open(os.path.join(tmp, stem + ".json"), "w") as fh:
                json.dump({**spec, "label": _grid_dict(volume, stem + ".nii.gz")}, fh, indent=1)
            rows.append(_record(volume, spec["name"], k, os.path.join(out_dir, stem + ".nii.gz"),
                                os.path.join(out_dir, stem + ".json")))
    return rows
