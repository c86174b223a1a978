"""An MRI-like phantom family for testing `less mri-label`, written apart from `lesscli.mri.synth`.

Own geometry (signed distances in mm, no `lesscli.phantom`) and own image model, so that the
segmentation is tested on volumes it was not developed with: an octagonal hydrogel insert with a
silicone skin and base, 1-3 inclusions (spheres, or spheroids with ``inclusion_aspect``) each on a
cylindrical pillar standing on the base; posed base down or up along array axis 0, rotated, shifted
and optionally tilted (:class:`Case`); partial volume, a slight blur, a smooth multiplicative bias and
Rician noise (:func:`generate`).

The truth classifies voxel centres: inclusion inside a sphere, pillar inside a cylinder and inside the
hydrogel cavity (its foot in the base stays insert), insert inside the octagonal prism.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

AIR, INSERT, PILLAR, INCLUSION = 0, 1, 2, 3
MIN_GAP_MM = 2.0               # between inclusions, and from an inclusion to the skin
PLACEMENT_TRIES = 400
MIN_INSERT_MM = 28.0           # the shortest insert drawn (the published phantoms' are 30 mm)


@dataclass(frozen=True)
class Case:
    """One volume of the family (lengths in mm; spacing per array axis 0, 1, 2 with axis 0 the insert axis;
    ``pillar_mm`` 0: the inclusions float without pillars)."""

    seed: int
    spacing_mm: tuple[float, float, float] = (0.7, 0.7, 0.9)
    inclusion_mm: tuple[float, ...] = (12.0,)
    pillar_mm: float = 3.0
    pillar_height_mm: tuple[float, ...] = (6.0,)
    base_up: bool = False
    silicone_brighter: bool = False
    noise: float = 0.05
    bias: float = 0.25
    yaw_deg: float | None = None
    width_mm: float = 62.0
    skin_mm: float = 2.5
    base_mm: float = 3.0
    inclusion_aspect: float = 1.0
    partial_volume: str = "ramp"
    # each sphere drawn this much wider in radius, where it was laid out (`perturbed`)
    sphere_margin_mm: float = 0.0
    # the highest sphere this far under the skin (None: MIN_GAP_MM and 0-4 mm more)
    skin_gap_mm: float | None = None
    tilt_deg: float = 0.0               # the insert's axis tilted off array axis 0 by this much
    tilt_azimuth_deg: float = 0.0       # about the in-plane axis at this angle from array axis 1 to axis 2


PARTIAL_VOLUMES = ("ramp", "box")
BOX_POINTS = 8                 # sub-voxel points per axis of the box partial volume


@dataclass
class Volume:
    """A generated scan: image and truth (array axes 0, 1, 2), spacing, and the drawn layout."""

    image: np.ndarray | None        # None: drawn without it (`generate(case, image=False)`)
    truth: np.ndarray
    spacing_mm: np.ndarray
    centres_index: np.ndarray       # (n, 3) inclusion centres as (fractional) array indices
    height_mm: float
    case: Case
    # the base's surface under the filling, as a (fractional) index along axis 0
    base_index: float
    #                                   (at the scan's lateral centre)
    # (n, 3) where each inclusion's axis meets the base's surface, as array indices
    feet_index: np.ndarray
    # the insert's axis in the array frame (unit, mm), from the base to the top
    axis_mm: np.ndarray

    def outer_indices(self) -> tuple[float, float]:
        """The insert's outer faces normal to its axis, the base's and the top skin's, as (fractional) indices
        along axis 0."""
        down = (-1.0 if self.case.base_up else 1.0) / self.spacing_mm[0]
        base_face = self.base_index - self.case.base_mm * down
        return base_face, base_face + self.height_mm * down

    def undecided_slices(self, surfaces: tuple[float, ...] | None = None) -> np.ndarray:
        """(axis-0 length,) bool: the slices whose voxel centres lie nearer one of ``surfaces`` (flat, normal
        to axis 0, as fractional indices; default: the base's surface under the filling) than half the box
        partial volume's sub-voxel step. A flat surface anywhere in that band leaves the same points of each
        box on either side, so the image is the same whichever side of it the centres (and the truth) are; the
        ramp is
        continuous and leaves none, and a tilted insert's surfaces are not normal to axis 0."""
        k = np.arange(self.truth.shape[0])
        flat = self.case.partial_volume == "box" and self.case.tilt_deg == 0.0
        band = 0.5 / BOX_POINTS if flat else 0.0
        at = (self.base_index,) if surfaces is None else surfaces
        return np.any([np.abs(k - s) < band for s in at], axis=0)


def _octagon_sd(x: np.ndarray, y: np.ndarray, apothem: float) -> np.ndarray:
    """Signed distance (exact inside, close outside) to a regular octagon with flats normal to x and y."""
    c = math.sqrt(0.5)
    faces = [np.abs(x), np.abs(y), np.abs(c * (x + y)), np.abs(c * (x - y))]
    return np.maximum.reduce(faces) - apothem


def _tilt(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """Rotation by ``tilt_deg`` about the unit axis (0, cos azimuth, sin azimuth) of the array frame."""
    t, a = math.radians(tilt_deg), math.radians(azimuth_deg)
    k = np.array([0.0, math.cos(a), math.sin(a)])
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return math.cos(t) * np.eye(3) + math.sin(t) * cross + (1.0 - math.cos(t)) * np.outer(k, k)


def _slab_sd(z: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.maximum(lo - z, z - hi)


def _layout(case: Case, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Inclusion centres (x, y, z mm) and the insert height that holds the tallest pillar plus sphere."""
    radii = 0.5 * np.asarray(case.inclusion_mm, dtype=float)
    heights = np.asarray(case.pillar_height_mm, dtype=float)
    gap = MIN_GAP_MM if case.skin_gap_mm is None else case.skin_gap_mm
    need = float(np.max(case.base_mm + heights + 2 * radii)) + gap + case.skin_mm
    if case.skin_gap_mm is not None and need < MIN_INSERT_MM - 1e-6:       # (the sum's rounding)
        raise ValueError(f"case {case}: a skin gap needs posts and spheres reaching {MIN_INSERT_MM:g} mm "
                         "less the gap and skin")
    height = max(MIN_INSERT_MM, need) + (float(rng.uniform(0.0, 4.0)) if case.skin_gap_mm is None else 0.0)
    apothem = 0.5 * case.width_mm - case.skin_mm
    wide = radii * max(1.0, case.inclusion_aspect)             # in-plane reach (a spheroid's long axis)
    for _ in range(PLACEMENT_TRIES):
        xy = rng.uniform(-apothem, apothem, (len(radii), 2))
        inside = _octagon_sd(xy[:, 0], xy[:, 1], apothem) <= -(wide + MIN_GAP_MM)
        dist = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(radii)) * 1e9
        if inside.all() and (dist >= wide[:, None] + wide[None] + MIN_GAP_MM).all():
            z = case.base_mm + heights + radii
            return np.column_stack([xy, z]), height
    raise ValueError(f"case {case}: could not place the inclusions")


def _fill(sd: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Partial-volume fill in [0, 1] of each voxel from the signed distance at its centre (mm)."""
    grads = np.gradient(sd, *spacing)
    norm = np.sqrt(sum(g * g for g in grads))
    safe = np.maximum(norm, 1e-6)
    width = sum(np.abs(g) / safe * s for g, s in zip(grads, spacing))
    width = np.where(norm > 0.1, width, float(np.mean(spacing)))
    return np.clip(0.5 - sd / width, 0.0, 1.0)


def _bias(points: list[np.ndarray], amplitude: float, rng: np.random.Generator) -> np.ndarray:
    """exp(amplitude * g), g in [-1, 1]: a linear ramp and two broad Gaussian bumps."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    g = sum(d * p for d, p in zip(direction, points)) / 40.0
    for _ in range(2):
        centre = rng.uniform(-30.0, 30.0, 3)
        width = float(rng.uniform(25.0, 45.0))
        r2 = sum((p - c) ** 2 for p, c in zip(points, centre))
        g = g + float(rng.choice([-1.0, 1.0])) * np.exp(-r2 / (2 * width ** 2))
    g = g - 0.5 * (g.max() + g.min())
    return np.exp(amplitude * g / max(float(np.abs(g).max()), 1e-6))


def _spheroid_sd(dx, dy, dz, radius: float, aspect: float):
    """Signed distance (mm) to a ball of ``radius``, or to its spheroid stretched ``aspect`` times along x
    (the level-set value over its gradient: exact on the surface, first order near it)."""
    if aspect == 1.0:
        return np.sqrt(dx * dx + dy * dy + dz * dz) - radius
    u = dx / aspect
    q = np.sqrt(u * u + dy * dy + dz * dz)
    grad = np.sqrt((u / aspect) ** 2 + dy * dy + dz * dz) / np.maximum(q, 1e-9)
    return (q - radius) / np.maximum(grad, 1e-9)


def _box_fills(body: np.ndarray, silicone: np.ndarray, grid: list[np.ndarray], spacing: np.ndarray,
               distances_at) -> tuple[np.ndarray, np.ndarray]:
    """Shares of each voxel's box inside body and silicone and inside body: the mean over
    ``BOX_POINTS``^3 points of the box where a surface passes within half the box's diagonal of its
    centre (a little more, as the distances are exact only inside), the centre's side elsewhere."""
    inside_body, inside_sil = body <= 0, silicone <= 0
    f_both, f_body = (inside_body & inside_sil).astype(float), inside_body.astype(float)
    reach = 0.6 * float(np.linalg.norm(spacing))
    near = np.nonzero((np.abs(body) < reach) | (np.abs(silicone) < reach))
    centres = [g[i] for g, i in zip(grid, near)]
    offsets = ((np.arange(BOX_POINTS) + 0.5) / BOX_POINTS - 0.5)
    both, inside = np.zeros(near[0].size), np.zeros(near[0].size)
    for o0 in offsets * spacing[0]:
        for o1 in offsets * spacing[1]:
            for o2 in offsets * spacing[2]:
                b, si = distances_at(centres[0] + o0, centres[1] + o1, centres[2] + o2)
                inside += b <= 0
                both += (b <= 0) & (si <= 0)
    f_both[near], f_body[near] = both / BOX_POINTS ** 3, inside / BOX_POINTS ** 3
    return f_both, f_body


def generate(case: Case, image: bool = True) -> Volume:
    """Generate the scan and truth of ``case`` (deterministic in ``case.seed``); ``image`` False: the truth
    and layout alone (``Volume.image`` None), as drawn with it.

    Partial volume (``partial_volume``): ``ramp``, a voxel's fill is a linear ramp of the signed distance at
    its centre over its width measured along the surface normal (exact for a flat surface, but it adds
    tissue around a thin convex structure: a post's cross-section grows by about (voxel / diameter)^2 / 3),
    or ``box``, the share of each voxel's box inside each tissue (an 8 x 8 x 8 point average near the
    surfaces, conserving each tissue's amount); then a slight Gaussian blur. The bias is ``exp(b g)``, g a
    linear ramp plus two broad Gaussian bumps scaled to [-1, 1] (not a polynomial and not cosines); the
    noise is Rician, ``|s + n1 + i n2|``, with sigma relative to the brighter tissue.
    """
    from scipy import ndimage

    rng = np.random.default_rng(case.seed)
    centres, height = _layout(case, rng)
    spacing = np.asarray(case.spacing_mm, dtype=float)
    radius_xy = 0.5 * case.width_mm / math.cos(math.pi / 8)
    margin = float(rng.uniform(3.0, 6.0))
    tilt = math.radians(case.tilt_deg)
    extent = np.array([height * math.cos(tilt) + 2 * radius_xy * math.sin(tilt),
                       2 * radius_xy + height * math.sin(tilt),
                       2 * radius_xy + height * math.sin(tilt)]) + 2 * margin
    shape = tuple(math.ceil(e / s) for e, s in zip(extent, spacing))
    grid = [(np.arange(n) - (n - 1) / 2) * s for n, s in zip(shape, spacing)]
    a0, a1, a2 = np.meshgrid(*grid, indexing="ij", sparse=True)
    yaw = math.radians(float(rng.uniform(0, 360)) if case.yaw_deg is None else case.yaw_deg)
    shift = rng.uniform(-2.0, 2.0, 3)
    c, s = math.cos(yaw), math.sin(yaw)
    radii = 0.5 * np.asarray(case.inclusion_mm) + case.sphere_margin_mm
    # the upright frame's axes in the array frame (columns)
    rot = _tilt(case.tilt_deg, case.tilt_azimuth_deg)

    def distances(a0, a1, a2):
        """Signed distances (mm) of body, cavity, spheres and pillars at array-frame points (broadcast)."""
        p = (a0 - shift[0], a1 - shift[1], a2 - shift[2])
        if case.tilt_deg:
            p = tuple(rot[0, i] * p[0] + rot[1, i] * p[1] + rot[2, i] * p[2] for i in range(3))
        u, v = p[2], p[1]
        x, y = c * u + s * v, -s * u + c * v                    # phantom x, y (rotation about axis 0)
        z = p[0] * (-1.0 if case.base_up else 1.0) + 0.5 * height
        body = np.maximum(_octagon_sd(x, y, 0.5 * case.width_mm), _slab_sd(z, 0.0, height))
        cavity = np.maximum(_octagon_sd(x, y, 0.5 * case.width_mm - case.skin_mm),
                            _slab_sd(z, case.base_mm, height - case.skin_mm))
        spheres = [_spheroid_sd(x - cx, y - cy, z - cz, r, case.inclusion_aspect)
                   for (cx, cy, cz), r in zip(centres, radii)]
        pillars = [np.maximum(np.sqrt((x - cx) ** 2 + (y - cy) ** 2) - 0.5 * case.pillar_mm,
                              _slab_sd(z, case.base_mm - 1.0, cz))
                   for cx, cy, cz in centres] if case.pillar_mm > 0 else []
        return body, cavity, spheres, pillars

    def silicone_of(cavity, spheres, pillars):
        return np.minimum.reduce([-cavity] + spheres + pillars)

    def body_and_silicone(p0, p1, p2):
        body, cavity, spheres, pillars = distances(p0, p1, p2)
        return body, silicone_of(cavity, spheres, pillars)

    body, cavity, spheres, pillars = distances(a0, a1, a2)
    silicone = silicone_of(cavity, spheres, pillars)
    truth = np.where(body <= 0, INSERT, AIR).astype(np.uint8)
    if pillars:
        truth[(np.minimum.reduce(pillars) <= 0) & (cavity <= 0) & (body <= 0)] = PILLAR
    truth[(np.minimum.reduce(spheres) <= 0) & (body <= 0)] = INCLUSION
    sign = -1.0 if case.base_up else 1.0

    def index_of(x, y, z):
        """Array indices of phantom points (mm)."""
        upright = np.column_stack([(z - 0.5 * height) * sign, s * x + c * y, c * x - s * y])
        return (upright @ rot.T + shift) / spacing + (np.asarray(shape) - 1) / 2

    centres_index = index_of(centres[:, 0], centres[:, 1], centres[:, 2])
    feet_index = index_of(centres[:, 0], centres[:, 1], np.full(len(centres), case.base_mm))
    base_mm = ((case.base_mm - 0.5 * height) * sign + rot[1, 0] * shift[1] + rot[2, 0] * shift[2]) / rot[0, 0]
    # at the lateral centre (a1 = a2 = 0 mm)
    base = (base_mm + shift[0]) / spacing[0] + (shape[0] - 1) / 2
    volume = Volume(None, truth, spacing, centres_index, height, case, float(base), feet_index,
                    sign * rot[:, 0])
    if not image:
        return volume
    if case.silicone_brighter:
        sil_level, gel_level = 1.0, float(rng.uniform(0.4, 0.6))
    else:
        sil_level, gel_level = float(rng.uniform(0.4, 0.6)), 1.0
    if case.partial_volume == "box":
        f_sil_body, f_body = _box_fills(body, silicone, grid, spacing, body_and_silicone)
        clean = sil_level * f_sil_body + gel_level * (f_body - f_sil_body)
    elif case.partial_volume == "ramp":
        f_body, f_sil = _fill(body, spacing), _fill(silicone, spacing)
        clean = f_body * (sil_level * f_sil + gel_level * (1.0 - f_sil))
    else:
        raise ValueError(f"partial_volume must be one of {PARTIAL_VOLUMES}, got {case.partial_volume!r}")
    clean = ndimage.gaussian_filter(clean, sigma=0.5) * _bias([a0, a1, a2], case.bias, rng)
    sigma = case.noise * max(sil_level, gel_level)
    real = clean + rng.normal(0.0, sigma, shape)
    imag = rng.normal(0.0, sigma, shape)
    return replace(volume, image=np.sqrt(real * real + imag * imag).astype(np.float32))


# Bands of the family: each parameter is drawn uniformly from its full range.
RANGES = {
    "pillar_mm": (1.5, 4.0), "pillar_height_mm": (1.0, 15.0), "inclusion_mm": (6.0, 16.0),
    "noise": (0.02, 0.1), "bias": (0.1, 0.4), "spacing_mm": (0.4, 1.2),
}
TILT_DEG = (0.0, 10.0)          # `tilted`: the insert's axis off array axis 0, degrees


def draw_case(seed: int) -> Case:
    """A case with every parameter drawn from the family's ranges (seeded)."""
    rng = np.random.default_rng([19, seed])
    n = int(rng.integers(1, 4))
    spacing = tuple(float(v) for v in np.round(rng.uniform(*RANGES["spacing_mm"], 2), 2))
    return Case(seed=seed, spacing_mm=(spacing[0], spacing[1], spacing[1]) if rng.random() < 0.5
                else (spacing[0], spacing[1], float(np.round(rng.uniform(*RANGES["spacing_mm"]), 2))),
                inclusion_mm=tuple(float(v) for v in np.round(rng.uniform(*RANGES["inclusion_mm"], n), 1)),
                pillar_mm=float(np.round(rng.uniform(*RANGES["pillar_mm"]), 2)),
                pillar_height_mm=tuple(float(v)
                                       for v in np.round(rng.uniform(*RANGES["pillar_height_mm"], n), 1)),
                base_up=bool(rng.random() < 0.5), silicone_brighter=bool(rng.random() < 0.5),
                noise=float(np.round(rng.uniform(*RANGES["noise"]), 3)),
                bias=float(np.round(rng.uniform(*RANGES["bias"]), 3)))


def tilted(case: Case) -> Case:
    """``case`` with the insert's axis tilted off array axis 0 by TILT_DEG about an in-plane axis at any
    azimuth
    (seeded by the case)."""
    rng = np.random.default_rng([50, case.seed])
    return replace(case, tilt_deg=float(np.round(rng.uniform(*TILT_DEG), 2)),
                   tilt_azimuth_deg=float(np.round(rng.uniform(0.0, 360.0), 1)))


def perturbed(case: Case, radius_mm: float = 0.0, base_mm: float = 0.0, sphere_mm: float = 0.0) -> Case:
    """``case`` with each post ``radius_mm`` wider, the base's surface under the filling ``base_mm``
    further from the insert's outer surface (the posts that much shorter) and each sphere ``sphere_mm``
    wider in radius about its centre, all else as drawn: the same layout, rotation, levels, bias and noise
    draws (the spheres' centres stay where they are)."""
    return replace(case, pillar_mm=case.pillar_mm + 2.0 * radius_mm, base_mm=case.base_mm + base_mm,
                   pillar_height_mm=tuple(h - base_mm for h in case.pillar_height_mm),
                   sphere_margin_mm=case.sphere_margin_mm + sphere_mm)


def pillar_voxels_wide(case: Case) -> float:
    """The pillar's diameter in voxels of the coarser in-plane spacing (axes 1 and 2)."""
    return case.pillar_mm / max(case.spacing_mm[1], case.spacing_mm[2])


def dice(a: np.ndarray, b: np.ndarray) -> float:
    """Dice of two masks; 1.0 when both are empty."""
    total = int(a.sum()) + int(b.sum())
    return 1.0 if total == 0 else 2.0 * int((a & b).sum()) / total


def scores(labels: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Dice per class of a segmentation against the truth."""
    return {name: dice(labels == code, truth == code)
            for code, name in ((INSERT, "insert"), (PILLAR, "pillar"), (INCLUSION, "inclusion"))}


def insert_scores(labels: np.ndarray, volume: Volume) -> dict[str, float]:
    """The insert's Dice, and its Dice without the slices the box partial volume leaves undecided at the
    insert's outer faces (:meth:`Volume.outer_indices`; the same as its Dice under the ramp)."""
    decided = ~volume.undecided_slices(volume.outer_indices())[:, None, None]
    ours, true = labels == INSERT, volume.truth == INSERT
    return {"dice_insert": dice(ours, true), "dice_insert_decided": dice(ours & decided, true & decided)}


def base_error_mm(base, volume: Volume) -> float:
    """How far a found base surface (``normal . x = offset_mm``, x in mm of array index times spacing, the
    normal into the base: :class:`lesscli.mri.pillar.BaseSurface`) lies past the true one, along axis 0
    at the scan's lateral centre (positive: into the base)."""
    spacing = volume.spacing_mm
    lateral = (np.asarray(volume.truth.shape) - 1) / 2 * spacing
    at = (base.offset_mm - base.normal[1] * lateral[1] - base.normal[2] * lateral[2]) / base.normal[0]
    return float((at - volume.base_index * spacing[0]) * np.sign(base.normal[0]))


def post_errors(posts: list, volume: Volume, reach_mm: float = 3.0) -> list[dict]:
    """Per inclusion, how the post found under it (:class:`lesscli.mri.pillar.Post`, the one whose foot lies
    nearest its axis, within ``reach_mm``) differs from the truth: diameter (as the scan measured it, also
    where the one drawn was given) and height (found minus true) and the foot's distance from the true axis,
    mm; None where no post is that near."""
    spacing = volume.spacing_mm
    feet = np.array([p.foot_mm[1:] for p in posts]).reshape(-1, 2)
    rows = []
    for k, foot in enumerate(volume.feet_index):
        off = np.linalg.norm(feet - foot[1:] * spacing[1:], axis=1)
        if not len(off) or off.min() > reach_mm:
            rows.append({"post_diameter_error_mm": None, "post_height_error_mm": None,
                         "post_offset_mm": None})
            continue
        post = posts[int(np.argmin(off))]
        radius = post.radius_mm if post.measured_radius_mm is None else post.measured_radius_mm
        rows.append({"post_diameter_error_mm": 2.0 * radius - volume.case.pillar_mm,
                     "post_height_error_mm": post.height_mm - volume.case.pillar_height_mm[k],
                     "post_offset_mm": float(off.min())})
    return rows


def inclusion_scores(labels: np.ndarray, volume: Volume) -> list[dict]:
    """Per inclusion: Dice of inclusion and pillar in its cell (voxels nearer its centre across the axis), and
    the pillar's Dice without the slices the box partial volume leaves undecided at the base
    (:meth:`Volume.undecided_slices`; the same as the pillar's Dice under the ramp).

    Cells split the volume between the inclusions by the distance across the insert's axis from each
    inclusion's centre (the plane of axes 1 and 2 where the insert is not tilted).
    """
    truth, spacing = volume.truth, volume.spacing_mm
    if volume.case.tilt_deg:
        grid = np.meshgrid(*(np.arange(k) * h for k, h in zip(truth.shape, spacing)), indexing="ij",
                           sparse=True)
        d2 = []
        for c in volume.centres_index:
            d = [g - ci * h for g, ci, h in zip(grid, c, spacing)]
            along = sum(n * di for n, di in zip(volume.axis_mm, d))
            d2.append(sum(di * di for di in d) - along * along)
    else:
        a1, a2 = np.meshgrid(*(np.arange(k) * h for k, h in zip(truth.shape[1:], spacing[1:])), indexing="ij")
        d2 = [(a1 - c[1] * spacing[1]) ** 2 + (a2 - c[2] * spacing[2]) ** 2 for c in volume.centres_index]
    cell_of = np.argmin(np.stack(d2), axis=0)
    decided = ~volume.undecided_slices()[:, None, None]
    rows = []
    for k in range(len(volume.centres_index)):
        cell = np.broadcast_to(cell_of == k, truth.shape)
        pillar, true_pillar = (labels == PILLAR) & cell, (truth == PILLAR) & cell
        rows.append({"inclusion_mm": volume.case.inclusion_mm[k],
                     "pillar_height_mm": volume.case.pillar_height_mm[k],
                     "dice_inclusion": dice((labels == INCLUSION) & cell, (truth == INCLUSION) & cell),
                     "dice_pillar": dice(pillar, true_pillar),
                     "dice_pillar_decided": dice(pillar & decided, true_pillar & decided)})
    return rows
