"""Synthetic MRI-like volumes of a phantom, with their true labels on the same grid.

The scanner frame is a rigid pose of the phantom frame: a scanner point ``s = R p + t`` for a phantom
point ``p`` (both x, y, z in mm). The volume is sampled on an axis-aligned grid in the scanner frame,
stored (D, H, W) = (z, y, x) like :class:`lesscli.io.labels.LabelVolume`.

Image model, in this order: tissue levels per material (silicone brighter or darker than the hydrogel,
air ~0), partial-volume averaging over ``supersample**3`` sub-voxel points (in the band of voxels
where materials meet; elsewhere the voxel is uniform), a smooth multiplicative
bias field ``exp(a * f)`` with ``f`` a sum of a few low-frequency cosines, and Rician noise
``|s + n1 + i n2|`` with ``n1, n2 ~ N(0, sigma)``. The true labels classify the voxel centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError
from lesscli.geometry.rotations import axis_rotation
from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, PILLAR, LabelVolume
from lesscli.phantom.geometry import Phantom

CHUNK_POINTS = 1_000_000        # points classified per batch (bounds memory on big grids)
BODY_PAD_MM = 1.0              # bounding-box pad before the exact inside test
BIAS_TERMS = 4                  # cosines in the bias field
# Label code per Phantom.material_index code (outside, skin, filling, pillar, inclusion).
MATERIAL_LABELS = np.array([BACKGROUND, INSERT, INSERT, PILLAR, INCLUSION], dtype=np.uint8)


@dataclass(frozen=True)
class MRIParams:
    """Acquisition and appearance of a synthetic scan.

    Attributes:
        spacing_mm: (dz, dy, dx) voxel size in mm.
        shape: (D, H, W) grid; None fits the posed phantom plus ``margin_mm`` on every side.
        margin_mm: air around the phantom when ``shape`` is None.
        supersample: sub-samples per axis for partial-volume averaging (1 = none).
        silicone_brighter: silicone (skin, pillar, inclusion) brighter than the hydrogel filling.
        dark_level, bright_level, air_level: tissue intensities before bias and noise.
        noise_sigma: Rician noise sigma, in units of ``bright_level``.
        bias_amplitude: peak |log| of the multiplicative bias field (0.3 = about +-35 %).
        bias_wavelength_mm: shortest wavelength of the bias field cosines.
        max_tilt_deg: largest tilt of the phantom's z axis away from the scanner's z.
        max_shift_mm: largest offset of the phantom centre from the grid centre, per axis.
        yaw_deg: in-plane rotation; None draws it uniformly in [0, 360).
    """

    spacing_mm: tuple[float, float, float] = (0.5, 0.5, 0.5)
    shape: tuple[int, int, int] | None = None
    margin_mm: float = 5.0
    supersample: int = 2
    silicone_brighter: bool = False
    dark_level: float = 0.45
    bright_level: float = 1.0
    air_level: float = 0.0
    noise_sigma: float = 0.04
    bias_amplitude: float = 0.25
    bias_wavelength_mm: float = 120.0
    max_tilt_deg: float = 8.0
    max_shift_mm: float = 2.0
    yaw_deg: float | None = None


@dataclass
class SyntheticMRI:
    """A synthetic scan and its truth.

    Attributes:
        image: (D, H, W) float32 intensities.
        labels: true labels on the same grid (origin/spacing in the scanner frame, mm).
        rotation: (3, 3) R of the pose, scanner = R @ phantom + t.
        translation_mm: (3,) t, x, y, z in mm.
        yaw_deg: in-plane rotation drawn for the pose.
        params: the parameters used.
    """

    image: np.ndarray
    labels: LabelVolume
    rotation: np.ndarray
    translation_mm: np.ndarray
    yaw_deg: float
    params: MRIParams = field(default_factory=MRIParams)


def random_pose(params: MRIParams, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """(3, 3) rotation: yaw about z, then a tilt of at most ``max_tilt_deg`` about a random horizontal
    axis."""
    yaw_deg = float(rng.uniform(0.0, 360.0)) if params.yaw_deg is None else float(params.yaw_deg)
    tilt = math.radians(params.max_tilt_deg) * float(rng.uniform(0.0, 1.0))
    azimuth = float(rng.uniform(0.0, 2 * math.pi))
    tilt_rot = axis_rotation("z", azimuth) @ axis_rotation("x", tilt) @ axis_rotation("z", -azimuth)
    return tilt_rot @ axis_rotation("z", math.radians(yaw_deg)), yaw_deg


def _grid(phantom: Phantom, rotation: np.ndarray, params: MRIParams,
          rng: np.random.Generator) -> tuple[tuple[int, int, int], np.ndarray, np.ndarray]:
    """Grid shape, origin (z, y, x mm) and the translation that places the phantom in it."""
    spacing = np.asarray(params.spacing_mm, dtype=np.float64)
    outline = phantom.outline_xy()
    corners = np.array([[x, y, z] for x, y in outline for z in (-phantom.height_mm, 0.0)])
    posed = _apply(corners, rotation)
    centre_xyz = 0.5 * (posed.min(axis=0) + posed.max(axis=0))
    if params.shape is None:
        extent_zyx = ((posed.max(axis=0) - posed.min(axis=0))[::-1] + 2
                      * (params.margin_mm + params.max_shift_mm))
        shape = tuple(math.ceil(e / s) + 1 for e, s in zip(extent_zyx, spacing))
    else:
        shape = tuple(int(n) for n in params.shape)
    origin = -(np.asarray(shape) - 1) / 2 * spacing             # grid centred on 0
    shift = rng.uniform(-params.max_shift_mm, params.max_shift_mm, 3)
    translation = shift - centre_xyz
    return shape, origin, translation


def _apply(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(n, 3) points times a 3x3 matrix (row vectors: m @ p), by columns (faster than BLAS on thin arrays)."""
    return points[:, 0:1] * matrix[:, 0] + points[:, 1:2] * matrix[:, 1] + points[:, 2:3] * matrix[:, 2]


def _materials(phantom: Phantom, scanner_xyz: np.ndarray, rotation: np.ndarray,
               translation: np.ndarray) -> np.ndarray:
    """Material codes at (n, 3) scanner points (points far outside the body skip the exact test)."""
    out = np.zeros(len(scanner_xyz), dtype=np.int8)
    r_mm = phantom.apothem_mm / math.cos(math.pi / 8) + BODY_PAD_MM
    for lo in range(0, len(scanner_xyz), CHUNK_POINTS):
        pts = _apply(scanner_xyz[lo:lo + CHUNK_POINTS] - translation, rotation.T)   # R^T (s - t)
        near = ((pts[:, 2] > -phantom.height_mm - BODY_PAD_MM) & (pts[:, 2] < BODY_PAD_MM)
                & (np.abs(pts[:, 0]) < r_mm) & (np.abs(pts[:, 1]) < r_mm))
        out[lo:lo + CHUNK_POINTS][near] = phantom.material_index(pts[near])
    return out


def _voxel_points(shape, origin, spacing, offset_zyx) -> np.ndarray:
    axes = [origin[a] + spacing[a] * (np.arange(shape[a]) + offset_zyx[a]) for a in range(3)]
    z, y, x = np.meshgrid(*axes, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def _partial_volume(phantom: Phantom, centre: np.ndarray, levels: np.ndarray, origin: np.ndarray,
                    spacing: np.ndarray, rotation: np.ndarray, translation: np.ndarray, s: int) -> np.ndarray:
    """(D, H, W) float32 intensities averaged over s^3 sub-voxel points where materials meet.

    Voxels whose 3x3x3 neighbourhood holds one material keep that material's level; only the band
    where materials change is supersampled.
    """
    from scipy import ndimage

    image = levels[centre]
    if s == 1:
        return image
    band = ndimage.maximum_filter(centre, size=3) != ndimage.minimum_filter(centre, size=3)
    idx = np.argwhere(band).astype(np.float64)                        # (n, 3) z, y, x
    acc = np.zeros(len(idx), dtype=np.float32)
    subs = (np.arange(s) + 0.5) / s - 0.5
    for dz in subs:
        for dy in subs:
            for dx in subs:
                zyx = origin + spacing * (idx + (dz, dy, dx))
                acc += levels[_materials(phantom, zyx[:, ::-1].copy(), rotation, translation)]
    image[band] = acc / s ** 3
    return image


def _bias_field(shape, origin, spacing, params: MRIParams, rng: np.random.Generator) -> np.ndarray:
    """(D, H, W) float32 smooth multiplicative field exp(a f), f in [-1, 1]."""
    if params.bias_amplitude <= 0:
        return np.ones(shape, dtype=np.float32)
    axes = [(origin[a] + spacing[a] * np.arange(shape[a])).astype(np.float32) for a in range(3)]
    f = np.zeros(shape, dtype=np.float32)
    for _ in range(BIAS_TERMS):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        k = 2 * math.pi / params.bias_wavelength_mm * float(rng.uniform(0.5, 1.0))
        phase = float(rng.uniform(0, 2 * math.pi))
        arg = (k * direction[0] * axes[0][:, None, None] + k * direction[1] * axes[1][None, :, None]
               + k * direction[2] * axes[2][None, None, :] + phase)
        f += np.cos(arg).astype(np.float32)
    f /= max(float(np.abs(f).max()), 1e-6)
    return np.exp(params.bias_amplitude * f).astype(np.float32)


def synthesize(phantom: Phantom, rng: np.random.Generator, params: MRIParams = MRIParams()) -> SyntheticMRI:
    """An MRI-like volume of ``phantom`` in a random rigid pose, with its true labels.

    Args:
        phantom: the insert geometry (phantom frame, mm).
        rng: source of the pose, bias field and noise.
        params: acquisition and appearance.

    Returns:
        SyntheticMRI with a (D, H, W) float32 image and uint8 labels on the same grid.
    """
    rotation, yaw_deg = random_pose(params, rng)
    shape, origin, translation = _grid(phantom, rotation, params, rng)
    spacing = np.asarray(params.spacing_mm, dtype=np.float64)
    silicone, hydrogel = ((params.bright_level, params.dark_level) if params.silicone_brighter
                          else (params.dark_level, params.bright_level))
    levels = np.array([params.air_level, silicone, hydrogel, silicone, silicone], dtype=np.float32)
    centre = _materials(phantom, _voxel_points(shape, origin, spacing, (0, 0, 0)), rotation, translation)
    centre = centre.reshape(shape)
    labels = LabelVolume(MATERIAL_LABELS[centre], origin, spacing, f"{phantom.name}_synthetic")
    image = _partial_volume(phantom, centre, levels, origin, spacing, rotation, translation,
                            max(1, int(params.supersample)))
    image = image * _bias_field(shape, origin, spacing, params, rng)
    sigma = params.noise_sigma * params.bright_level
    if sigma > 0:
        real = image + rng.normal(0.0, sigma, shape).astype(np.float32)
        imag = rng.normal(0.0, sigma, shape).astype(np.float32)
        image = np.sqrt(real * real + imag * imag)
    return SyntheticMRI(image.astype(np.float32), labels, rotation, translation, yaw_deg, params)


def save_synthetic(result: SyntheticMRI, image_path: str, labels_path: str | None = None) -> None:
    """Write the image (float32 NIfTI, mm affine) and optionally its true labels (uint8 NIfTI), atomically."""
    from lesscli.io.atomic import atomic_path
    from lesscli.io.labels import save_nifti, save_nifti_array

    for path in (image_path, labels_path or ".nii"):
        if not path.endswith((".nii", ".nii.gz")):
            raise DataError(f"{path}: synthetic scans and labels are written as NIfTI (.nii.gz or .nii)")
    with atomic_path(image_path, ".nii.gz" if image_path.endswith(".gz") else ".nii") as tmp:
        save_nifti_array(tmp, result.image.astype(np.float32), result.labels)
    if labels_path:
        with atomic_path(labels_path, ".nii.gz" if labels_path.endswith(".gz") else ".nii") as tmp:
            save_nifti(tmp, result.labels)


def find_phantom(name_or_path: str) -> Phantom:
    """A catalogue insert by name (any catalogue, case-insensitive) or the first phantom of a .toml/.json
    file."""
    import os

    from lesscli.phantom.catalogue import CATALOGUES, load_phantom_file

    if os.path.splitext(name_or_path)[1] in (".toml", ".json"):
        return load_phantom_file(name_or_path)[0]
    inserts = {p.name.lower(): p for make in CATALOGUES.values() for p in make()}
    if name_or_path.lower() in inserts:
        return inserts[name_or_path.lower()]
    from lesscli.errors import closest

    hint = closest(name_or_path.lower(), inserts)
    raise DataError(f"unknown insert '{name_or_path}'" + (f"; did you mean '{inserts[hint].name}'?" if hint
                                                          else " (give a catalogue insert name or a "
                                                               ".toml/.json file)"))


def write_mri_set(out_dir: str, phantoms: list[Phantom], orientations, seed: int = 0,
                  params: MRIParams = MRIParams()) -> list[dict]:
    """Synthetic scans ``OUT/mri/<insert>_<k>.nii.gz`` and truths ``..._truth.nii.gz`` for each insert and k.

    Each scan draws its own pose, bias field and noise from ``seed``, the insert's index and k, so any
    subset of a set reproduces the same files. Returns one record per scan.
    """
    import os

    from lesscli.io.atomic import atomic_dir

    folder = os.path.join(out_dir, "mri")
    rows = []
    with atomic_dir(folder) as tmp:
        for i, base in enumerate(phantoms):
            for k in orientations:
                result = synthesize(base.rotated(k), np.random.default_rng([seed, i, k]), params)
                stem = f"{base.name}_{k}"
                save_synthetic(result, os.path.join(tmp, stem + ".nii.gz"),
                               os.path.join(tmp, stem + "_truth.nii.gz"))
                rows.append({"insert": base.name, "orientation": int(k),
                             "mri": os.path.join(folder, stem + ".nii.gz"),
                             "truth": os.path.join(folder, stem + "_truth.nii.gz"),
                             "shape": "x".join(map(str, result.image.shape)),
                             "yaw_deg": round(result.yaw_deg, 3)})
    return rows
