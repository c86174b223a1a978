"""Split the silicone inside an insert into skin (stays insert), inclusions and pillars, by morphology in mm.

- A thin shell along the insert's outer surface is set aside first: there, partial-volume voxels
  between the filling and the air can mimic the darker tissue.
- Inclusions: the opening of the remaining silicone by a ball thicker than the thickest pillar and
  skin (radius ``max(pillar, skin) / 2`` plus a quarter voxel): compact bodies survive, thin ones
  vanish; the rim (one voxel) that the opening shaves off a noisy sphere is given back.
- Pillars: what is left, per connected component, if it is a thin elongated column (second principal
  standard deviation of a solid cylinder of the largest allowed diameter, plus half a voxel) running
  along the insert axis (its smallest principal direction: the inserts are wider than tall); its foot
  is then restored into the shell, down to the base. A column touching no inclusion is kept as pillar
  with a warning.
- Everything else (the skin, partial-volume speckle) stays insert.

Openings and dilations use Euclidean distance transforms with the voxel spacing, so balls are round
in millimetres whatever the voxel shape.
"""

from __future__ import annotations

import math

import numpy as np

SHELL_VOXELS = 1.5              # shell thickness along the insert surface, in (largest) voxels
ELONGATION = 1.5                # first / second principal std of a column
MIN_PILLAR_LENGTH_VOXELS = 4.0  # shorter remnants are speckle
RIM_VOXELS = 1.0                # rim given back to each inclusion after the opening, in voxels
MAX_PILLAR_TILT_DEG = 30.0      # a pillar runs along the insert axis, within this angle
AXIS_SAMPLES = 200_000
BALL_MARGIN_VOXELS = 0.25       # the opening ball's radius exceeds the thickest pillar's by this


def _crop(mask: np.ndarray, pad: int) -> tuple[slice, ...]:
    idx = np.argwhere(mask)
    lo = np.maximum(idx.min(axis=0) - pad, 0)
    hi = np.minimum(idx.max(axis=0) + pad + 1, mask.shape)
    return tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))


def open_ball(mask: np.ndarray, radius_mm: float, spacing: np.ndarray) -> np.ndarray:
    """Morphological opening of ``mask`` by a ball of ``radius_mm`` (voxel-centre distances)."""
    from scipy import ndimage

    eroded = ndimage.distance_transform_edt(mask, sampling=spacing) > radius_mm
    if not eroded.any():
        return eroded
    return ndimage.distance_transform_edt(~eroded, sampling=spacing) <= radius_mm


def _principal(coords_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal standard deviations (descending) of (n, 3) points and the (3, 3) axes as columns."""
    centred = coords_mm - coords_mm.mean(axis=0)
    cov = np.einsum("ni,nj->ij", centred, centred) / max(len(coords_mm), 1)
    values, vectors = np.linalg.eigh(cov)
    return np.sqrt(np.maximum(values[::-1], 0.0)), vectors[:, ::-1]


def insert_axis(insert: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Unit vector (array-axis components, mm-scaled) of the insert's smallest principal direction.

    The octagonal inserts are wider than tall, so this is the direction of the pillars.
    """
    idx = np.argwhere(insert)
    if len(idx) > AXIS_SAMPLES:
        idx = idx[np.random.default_rng(0).choice(len(idx), AXIS_SAMPLES, replace=False)]
    return _principal(idx * spacing)[1][:, 2]


def _is_column(coords_mm: np.ndarray, max_diameter_mm: float, voxel_mm: float, axis: np.ndarray) -> bool:
    """A thin elongated body running along the insert axis."""
    stds, vectors = _principal(coords_mm)
    length_mm = stds[0] * math.sqrt(12.0)          # std of a uniform segment of that length
    return bool(stds[1] <= max_diameter_mm / 4 + 0.5 * voxel_mm and stds[0] >= ELONGATION * stds[1]
                and length_mm >= MIN_PILLAR_LENGTH_VOXELS * voxel_mm
                and abs(float(vectors[:, 0] @ axis)) >= math.cos(math.radians(MAX_PILLAR_TILT_DEG)))


def _pillars(rest: np.ndarray, inclusion: np.ndarray, spacing: np.ndarray, max_diameter_mm: float,
             axis: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, list[str], set[int]]:
    """Column components of ``rest``; warnings for columns not touching an inclusion; touched inclusion ids."""
    from scipy import ndimage
    from skimage.measure import label, regionprops

    voxel_mm = float(spacing.max())
    inc_ids, _ = ndimage.label(inclusion)
    near = ndimage.grey_dilation(inc_ids, size=3)
    pillar = np.zeros(rest.shape, dtype=bool)
    warnings, touched = [], set()
    for region in regionprops(label(rest, connectivity=1)):
        coords = region.coords
        if not _is_column(coords * spacing, max_diameter_mm, voxel_mm, axis):
            continue
        hit = set(np.unique(near[tuple(coords.T)]).tolist()) - {0}
        pillar[tuple(coords.T)] = True
        if not hit:
            centre = (np.round(coords.mean(axis=0)).astype(int) + offset).tolist()
            warnings.append(f"pillar not connected: a silicone column near voxel {centre} touches no inclusion")
        touched |= hit
    return pillar, warnings, touched


def _unanchored(pillar: np.ndarray, depth: np.ndarray, reach_mm: float, offset: np.ndarray) -> list[str]:
    """Warnings for pillar components that stop short of the insert's surface (the base)."""
    from scipy import ndimage

    comps, n = ndimage.label(pillar)
    if n == 0:
        return []
    lowest = ndimage.minimum(depth, comps, index=np.arange(1, n + 1))
    out = []
    for i in np.flatnonzero(np.asarray(lowest) > reach_mm) + 1:
        centre = (np.round(ndimage.center_of_mass(comps == i)).astype(int) + offset).tolist()
        out.append(f"pillar not connected to the base: the pillar near voxel {centre} stops inside the insert")
    return out


def split_silicone(silicone: np.ndarray, insert: np.ndarray, spacing_mm, pillar_max_diameter_mm: float,
                   skin_max_thickness_mm: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Pillar and inclusion masks from the silicone mask of an insert.

    Args:
        silicone: bool mask (any 3D shape) of silicone voxels inside the insert.
        insert: bool mask of the whole insert (holes filled).
        spacing_mm: (3,) voxel size per axis.
        pillar_max_diameter_mm: thickest pillar.
        skin_max_thickness_mm: thickest skin.

    Returns:
        (pillar mask, inclusion mask, warnings), masks of the input's shape.
    """
    from scipy import ndimage
    from skimage.measure import label

    spacing = np.asarray(spacing_mm, dtype=np.float64)
    pillar_full = np.zeros(insert.shape, dtype=bool)
    inclusion_full = np.zeros(insert.shape, dtype=bool)
    if not silicone.any():
        return pillar_full, inclusion_full, ["no inclusion found (no silicone inside the insert)"]
    box = _crop(insert, 2)
    # one voxel of padding: the distance transforms must see air beyond a scan's border too
    sil, ins = np.pad(silicone[box], 1), np.pad(insert[box], 1)
    voxel_mm = float(spacing.max())
    shell_mm = SHELL_VOXELS * voxel_mm
    depth = ndimage.distance_transform_edt(ins, sampling=spacing)
    core = sil & (depth > shell_mm)
    fine_mm = float(np.prod(spacing)) ** (1.0 / 3.0)        # mean voxel size (anisotropic grids)
    radius_mm = 0.5 * max(pillar_max_diameter_mm, skin_max_thickness_mm) + BALL_MARGIN_VOXELS * fine_mm
    opened = open_ball(core, radius_mm, spacing)
    min_voxels = 0.5 * (4 / 3) * math.pi * radius_mm ** 3 / float(np.prod(spacing))
    comps = label(opened, connectivity=1)
    sizes = np.bincount(comps.ravel())
    keep = np.flatnonzero(sizes >= min_voxels)
    inclusion = np.isin(comps, keep[keep > 0])
    if inclusion.any():     # give back the rim an opening shaves off a noisy, barely larger sphere
        inclusion |= core & (ndimage.distance_transform_edt(~inclusion, sampling=spacing) <= RIM_VOXELS * fine_mm)
    offset = np.array([b.start for b in box]) - 1              # padded crop -> input voxel index
    pillar, warnings, touched = _pillars(core & ~inclusion, inclusion, spacing, pillar_max_diameter_mm,
                                         insert_axis(ins, spacing), offset)
    if pillar.any():
        reach = ndimage.distance_transform_edt(~pillar, sampling=spacing) <= shell_mm + voxel_mm
        pillar |= sil & ~core & reach & ~inclusion
        warnings += _unanchored(pillar, depth, shell_mm + voxel_mm, offset)
    inc_ids, n_inclusions = ndimage.label(inclusion)
    if n_inclusions == 0:
        warnings.append("no inclusion found")
    for i in sorted(set(range(1, n_inclusions + 1)) - touched):
        centre = (np.round(ndimage.center_of_mass(inc_ids == i)).astype(int) + offset).tolist()
        warnings.append(f"pillar not connected: no pillar found under the inclusion near voxel {centre}")
    inner = (slice(1, -1),) * 3
    pillar_full[box], inclusion_full[box] = pillar[inner], inclusion[inner]
    return pillar_full, inclusion_full, warnings
