"""Split the silicone inside an insert into skin (stays insert), inclusions and pillars, by morphology in mm.

- A thin shell along the insert's outer surface is set aside first: there, partial-volume voxels
  between the filling and the air can mimic the darker tissue.
- Inclusions: the opening of the remaining silicone by a ball thicker than the thickest pillar and skin:
  compact bodies survive, thin ones vanish. A second, smaller ball finds inclusions too thin, voxel for
  voxel, for the first; of what it keeps apart from those, only round bodies are inclusions.
- Pillars: traced from each inclusion towards the base along the insert axis (:mod:`lesscli.mri.pillar`).
- Each inclusion's surface is drawn again from its local contrast or as its fitted ball, and takes back
  the pillar's voxels inside its sphere (:mod:`lesscli.mri.surface`).
- Everything else (the skin, partial-volume speckle) stays insert.

Openings and dilations use Euclidean distance transforms with the voxel spacing, so balls are round
in millimetres whatever the voxel shape.
"""

from __future__ import annotations

import math

import numpy as np

from lesscli.mri.ball import RIM_VOXELS
from lesscli.mri.pillar import find_pillars
from lesscli.mri.surface import junctions, local_surface

SHELL_VOXELS = 1.5              # shell thickness along the insert surface, in (largest) voxels
SMALL_BALL = 0.8                # a second, smaller ball for small inclusions (of the main ball's radius)
MAX_ELONGATION = 1.5            # ... kept where round: largest over smallest principal spread
BALL_MARGIN_VOXELS = 0.25       # the opening ball's radius exceeds the thickest pillar's by this
BOUNDARY_VOXELS = (1.0, 2.5)    # the layer around a body in which its surroundings are measured
# an inclusion lies in the filling; more silicone around: a pillar's foot, a corner
MAX_BOUNDARY_SILICONE = 0.3
# ... the fit leaves out the voxels this close to a post or the base, in voxels
BLUR_VOXELS = 1.0


def crop_box(mask: np.ndarray, pad: int) -> tuple[slice, ...]:
    """The bounding box of ``mask`` (not empty) widened by ``pad`` voxels (clipped to the array), read from
    its
    projections on the axes (listing its voxels' indices took a hundred times as long on a scan)."""
    box = []
    for ax, n in enumerate(mask.shape):
        seen = np.flatnonzero(mask.any(axis=tuple(a for a in range(mask.ndim) if a != ax)))
        box.append(slice(max(int(seen[0]) - pad, 0), min(int(seen[-1]) + pad + 1, n)))
    return tuple(box)


def open_ball(mask: np.ndarray, radius_mm: float, spacing: np.ndarray,
              depth_mm: np.ndarray | None = None) -> np.ndarray:
    """Morphological opening of ``mask`` by a ball of ``radius_mm`` (voxel-centre distances); ``depth_mm``:
    ``mask``'s distance transform where already taken (one serves the openings by every radius)."""
    from scipy import ndimage

    if depth_mm is None:
        depth_mm = ndimage.distance_transform_edt(mask, sampling=spacing)
    eroded = depth_mm > radius_mm
    if not eroded.any():
        return eroded
    return ndimage.distance_transform_edt(~eroded, sampling=spacing) <= radius_mm


def _ball_voxels(radius_mm: float, spacing: np.ndarray) -> float:
    """How many voxels of ``spacing`` a ball of ``radius_mm`` holds."""
    return (4 / 3) * math.pi * radius_mm ** 3 / float(np.prod(spacing))


def _without_pinholes(mask: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """``mask`` with its holes (face-connected) smaller than a ball of one largest voxel's radius filled.

    No structure of the phantoms is a pocket that small; noise makes them, a voxel or two below the
    threshold inside an inclusion, and a single one cuts the opening's erosion short by the ball's
    radius all round it: a 7.6 mm inclusion at noise 0.096 opened to a third of its body and was then
    taken for a thick spot in the silicone (seed 3022 of the family)."""
    from scipy import ndimage

    holes, _n = ndimage.label(~mask)
    small = np.bincount(holes.ravel()) < _ball_voxels(float(spacing.max()), spacing)
    small[0] = False
    return mask | small[holes]


def _rim(mask: np.ndarray, reach_mm: float, spacing: np.ndarray) -> np.ndarray:
    """The voxels outside ``mask`` within ``reach_mm`` of it (voxel-centre distances)."""
    from scipy import ndimage

    out = np.zeros(mask.shape, dtype=bool)
    if mask.any():
        box = crop_box(mask, math.ceil(reach_mm / float(spacing.min())) + 1)
        out[box] = (ndimage.distance_transform_edt(~mask[box], sampling=spacing) <= reach_mm) & ~mask[box]
    return out


def _principal(mask: np.ndarray, spacing: np.ndarray, boxes: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Principal standard deviations (descending, mm) of the centres of ``mask``'s voxels (a 3D bool or
    float array, each voxel weighted by its value) and the (3, 3) axes as columns; ``boxes``: of the
    voxels as boxes of ``spacing`` (each adds its own spread, side^2 / 12). The moments are summed from
    the mask's three 2D projections: every voxel counts, and no list of voxels is made."""
    spacing = np.asarray(spacing, dtype=np.float64)
    pairs = {(0, 1): mask.sum(axis=2, dtype=np.float64), (0, 2): mask.sum(axis=1, dtype=np.float64),
             (1, 2): mask.sum(axis=0, dtype=np.float64)}
    margins = [pairs[0, 1].sum(axis=1), pairs[0, 1].sum(axis=0), pairs[0, 2].sum(axis=0)]
    total = max(float(margins[0].sum()), np.finfo(float).tiny)
    coords = [np.arange(n) * s for n, s in zip(mask.shape, spacing)]
    coords = [c - float(m @ c) / total for c, m in zip(coords, margins)]
    cov = np.diag([float(m @ (c * c)) / total for c, m in zip(coords, margins)])
    for (i, j), p in pairs.items():
        cov[i, j] = cov[j, i] = float(coords[i] @ p @ coords[j]) / total
    if boxes:
        cov += np.diag(spacing ** 2 / 12.0)
    values, vectors = np.linalg.eigh(cov)
    return np.sqrt(np.maximum(values[::-1], 0.0)), vectors[:, ::-1]


def insert_axis(insert: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Unit vector (array-axis components, mm-scaled) of the insert's smallest principal direction.

    The octagonal inserts are wider than tall, so this is the direction of the pillars. Every voxel
    counts: a random 200 000 of them tilted the axis by up to 0.34 degrees (0.09 mm at the foot of a
    post 15 mm from its sphere's centre, where the line through that centre is tested against the
    post's own), against at most 0.15 over all of them (family seeds 7000-7039).
    """
    return _principal(insert, spacing)[1][:, 2]


def _opened(core: np.ndarray, radius_mm: float, spacing: np.ndarray,
            depth_mm: np.ndarray | None = None) -> np.ndarray:
    """The components of ``core`` opened by a ball of ``radius_mm`` holding at least half that ball
    (``depth_mm``: :func:`open_ball`'s)."""
    from skimage.measure import label

    comps = label(open_ball(core, radius_mm, spacing, depth_mm), connectivity=1)
    sizes = np.bincount(comps.ravel())
    keep = np.flatnonzero(sizes >= 0.5 * _ball_voxels(radius_mm, spacing))
    return np.isin(comps, keep[keep > 0])


def _round(candidates: np.ndarray, bodies: np.ndarray, radius_mm: float, spacing: np.ndarray,
           elongated: np.ndarray | None = None) -> np.ndarray:
    """The round components of ``candidates`` apart from ``bodies`` that hold at least half the volume of a
    ball of ``radius_mm`` (the rule of :func:`_opened`); ``elongated`` (a mask of the candidates' shape),
    where given, gets each such component that is not round.

    A small inclusion at coarse voxels can be too thin, voxel for voxel, for the ball that removes the
    thickest pillar, though it holds that ball's volume; a smaller ball keeps it, and with it any pillar
    thicker than that ball, joined to its inclusion into an elongated body, or short pieces of such a
    pillar. Round components (principal spreads within MAX_ELONGATION) are inclusions or pieces of a post
    (:func:`_off_axis`). Each voxel counts as its box: a 6 mm sphere at 1.1-1.2 mm voxels opened to
    3 x 3 x 4 voxels, whose centres spread 1.51 times more along one axis than across (their boxes 1.47).
    """
    from scipy import ndimage

    comps, _n = ndimage.label(candidates)
    known = set(np.unique(comps[bodies]).tolist())
    min_voxels = 0.5 * _ball_voxels(radius_mm, spacing)
    out = np.zeros(candidates.shape, dtype=bool)
    for i, sl in enumerate(ndimage.find_objects(comps), start=1):
        own = comps[sl] == i
        if i in known or int(own.sum()) < min_voxels:
            continue
        spread = _principal(own, spacing, boxes=True)[0]
        if spread[0] <= MAX_ELONGATION * max(spread[2], 1e-6):
            out[sl] |= own
        elif elongated is not None:
            elongated[sl] |= own
    return out


def _unexplained(elongated: np.ndarray, bodies: np.ndarray, axis: np.ndarray, spacing: np.ndarray) -> list:
    """Of the elongated components :func:`_round` left out that lie in the filling (:func:`_in_filling`),
    the centre indices of those off the axis of every body kept (laterally beyond its equal-volume radius
    from its centre): no piece of a body's post, no skin's corner, so perhaps a small inclusion the noise
    left too ragged to read as round (:func:`split_silicone` leaves out those past the base's surface, and
    those
    within the thickest skin of the insert's outer surface: a base without posts has no surface found)."""
    held = _centres_radii(bodies, spacing)[1]
    return [c / spacing for c, _r in _centres_radii(elongated, spacing)[1]
            if all(_lateral(c - centre, axis) >= r for centre, r in held)]


def _centres_radii(mask: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, list]:
    """The components of ``mask`` labelled, and each one's (centre in mm, equal-volume radius in mm)."""
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    index = np.arange(1, n + 1)
    volumes = ndimage.sum_labels(mask, labels, index) * float(np.prod(spacing))
    centres = np.asarray(ndimage.center_of_mass(mask, labels, index)).reshape(-1, 3) * spacing
    return labels, list(zip(centres, (0.75 * volumes / math.pi) ** (1.0 / 3.0)))


def _off_axis(pieces: np.ndarray, bodies: np.ndarray, axis: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """The components of ``pieces`` that lie off the axis of every component of ``bodies`` and of every larger
    piece kept: laterally (across the insert ``axis``) at least the smaller one's equal-volume radius from
    its centre. Every post stands on the base, so of two inclusions that close one's post would pass
    through the other: a piece that close to an inclusion's centre is a piece of its post.

    A 6.3 mm inclusion at 1.11 mm voxels and noise 0.085 opened to 0.92 of the ball's volume
    (:func:`_round`), pieces of a 4 mm post under its inclusion to more than half, and the foot of a 2.5 mm
    post on the base, under a 15.3 mm inclusion, to 1.01 of it.
    """
    out = np.zeros(pieces.shape, dtype=bool)
    held = _centres_radii(bodies, spacing)[1]
    labels, found = _centres_radii(pieces, spacing)
    for i in np.argsort([-r for _c, r in found]):
        centre, radius = found[i]
        if all(_lateral(centre - c, axis) >= min(radius, r) for c, r in held):
            out |= labels == i + 1
            held.append(found[i])
    return out


def _lateral(offset: np.ndarray, axis: np.ndarray) -> float:
    """Length of ``offset`` across the unit ``axis``."""
    return float(np.linalg.norm(offset - float(offset @ axis) * axis))


def _in_filling(bodies: np.ndarray, silicone: np.ndarray, insert: np.ndarray,
                spacing: np.ndarray) -> np.ndarray:
    """The bodies mostly surrounded by filling: silicone covers at most MAX_BOUNDARY_SILICONE of the layer
    BOUNDARY_VOXELS around each (inside the insert; a voxel away, so that the body's own rim does not
    count); thick spots where a pillar meets the base, or skin meets skin in a corner, are surrounded by
    silicone on one side."""
    from scipy import ndimage

    comps, _ = ndimage.label(bodies)
    keep = np.zeros(bodies.shape, dtype=bool)
    gap, reach = (v * float(spacing.max()) for v in BOUNDARY_VOXELS)
    pad = int(np.ceil(reach / float(spacing.min()))) + 1
    for i, sl in enumerate(ndimage.find_objects(comps), start=1):
        box = tuple(slice(max(a.start - pad, 0), a.stop + pad) for a in sl)
        own = comps[box] == i
        dist = ndimage.distance_transform_edt(~own, sampling=spacing)
        near = (dist > gap) & (dist <= reach) & insert[box]
        if near.any() and float(silicone[box][near].mean()) <= MAX_BOUNDARY_SILICONE:
            keep[box] |= own
    return keep


def _bodies(sil: np.ndarray, ins: np.ndarray, deep: np.ndarray, radius_mm: float,
            spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The inclusions' bodies in the silicone ``sil`` of the insert ``ins`` (both padded crops), from its
    voxels ``deep`` inside the insert: what an opening by a ball of ``radius_mm`` keeps in the filling, and
    the round pieces of one by a smaller ball off the axis of every body found so. The split passes a
    radius of ``max(pillar, skin) / 2`` plus a quarter voxel, and the rim (one largest voxel) that the
    opening shaves off a noisy sphere is given back.

    Returns:
        (bodies, the pieces the smaller ball kept that read elongated (:func:`_round`), the insert axis).
    """
    from scipy import ndimage

    core = _without_pinholes(sil & deep, spacing)
    depth = ndimage.distance_transform_edt(core, sampling=spacing)      # one transform for both openings
    opened = _opened(core, radius_mm, spacing, depth)
    elongated = np.zeros(core.shape, dtype=bool)
    pieces = _round(_opened(core, SMALL_BALL * radius_mm, spacing, depth), opened, radius_mm, spacing,
                    elongated)
    bodies = _in_filling(opened, sil, ins, spacing)
    axis = insert_axis(ins, spacing)
    if pieces.any():                                        # rare: labelling every scan's bodies costs
        bodies |= _off_axis(_in_filling(pieces, sil, ins, spacing), bodies, axis, spacing)
    return bodies, elongated, axis


def _left_out(pillar: np.ndarray, bodies: np.ndarray, base, blur_mm: float,
              spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """What an inclusion's ball fit leaves out: the voxels within ``blur_mm`` of a post (outside the bodies)
    or on the filling's side of the base's surface (:class:`lesscli.mri.pillar.BaseSurface`, None without a
    post); and the voxels past that surface, in the base (None without one)."""
    blurred = _rim(pillar, blur_mm, spacing) & ~bodies
    if base is None:
        return blurred, None
    past = base.past_mm(spacing, pillar.shape)
    beyond = past > 0
    return blurred | ((past > -blur_mm) & ~beyond), beyond


def split_silicone(silicone: np.ndarray, insert: np.ndarray, spacing_mm, pillar_max_diameter_mm: float,
                   skin_max_thickness_mm: float, fraction: np.ndarray | None = None,
                   inclusion_shape: str = "auto",
                   pillar_diameter_mm: float | None = None,
                   smoothing: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, list[str], list[dict]]:
    """Pillar and inclusion masks from the silicone mask of an insert; an inclusion without a pillar gets
    a warning.

    Args:
        silicone: bool mask (any 3D shape) of silicone voxels inside the insert.
        insert: bool mask of the whole insert (holes filled).
        spacing_mm: (3,) voxel size per axis.
        pillar_max_diameter_mm: thickest pillar.
        skin_max_thickness_mm: thickest skin.
        fraction: float image of the silicone fraction (0 hydrogel, 1 silicone) for tracing pillars;
            None uses the silicone mask itself.
        inclusion_shape: "auto", "image" or "ball" (:func:`lesscli.mri.surface.local_surface`).
        pillar_diameter_mm: the posts' diameter as cast, where known (:func:`find_pillars`); None: as
            measured.
        smoothing: (3,) sigma per axis, in voxels, of the denoising ``fraction`` had (:func:`find_pillars`).

    Returns:
        (pillar mask, inclusion mask, warnings, one dict per inclusion on how its surface was drawn
        (:func:`lesscli.mri.surface.local_surface`; centres in the input's voxel indices), the base's surface
        found under the pillars on the input's grid (:class:`lesscli.mri.pillar.BaseSurface`, None without a
        pillar), the posts drawn on the input's grid (:class:`lesscli.mri.pillar.Post`)), masks of the
        input's shape.
    """
    from scipy import ndimage

    spacing = np.asarray(spacing_mm, dtype=np.float64)
    pillar_full = np.zeros(insert.shape, dtype=bool)
    inclusion_full = np.zeros(insert.shape, dtype=bool)
    if not silicone.any():
        return (pillar_full, inclusion_full, ["no inclusion found (no silicone inside the insert)"], [], None,
                [])
    box = crop_box(insert, 2)
    # one voxel of padding: the distance transforms must see air beyond a scan's border too
    sil, ins = np.pad(silicone[box], 1), np.pad(insert[box], 1)
    voxel_mm = float(spacing.max())
    shell_mm = SHELL_VOXELS * voxel_mm
    depth = ndimage.distance_transform_edt(ins, sampling=spacing)
    fine_mm = float(np.prod(spacing)) ** (1.0 / 3.0)        # mean voxel size (anisotropic grids)
    radius_mm = 0.5 * max(pillar_max_diameter_mm, skin_max_thickness_mm) + BALL_MARGIN_VOXELS * fine_mm
    bodies, elongated, axis = _bodies(sil, ins, depth > shell_mm, radius_mm, spacing)
    frac = np.pad(fraction[box], 1) if fraction is not None else sil.astype(np.float32)
    offset = np.array([b.start for b in box]) - 1              # padded crop -> input voxel index
    inc_ids, n_inclusions = ndimage.label(bodies)
    warnings = [] if n_inclusions else ["no inclusion found"]
    lost = (_unexplained(_in_filling(elongated, sil, ins, spacing), bodies, axis, spacing) if elongated.any()
            else [])
    deep = ins & (depth > shell_mm)
    pillar, missing, base, posts, run_on = find_pillars(frac, ins, inc_ids, n_inclusions, spacing,
                                                        axis, pillar_max_diameter_mm, deep,
                                                        pillar_diameter_mm, smoothing)
    blurred, beyond = _left_out(pillar, bodies, base, BLUR_VOXELS * voxel_mm, spacing)
    for centre in lost:
        at = tuple(np.round(centre).astype(int))
        if depth[at] <= skin_max_thickness_mm + voxel_mm or (beyond is not None and beyond[at]):
            # within a skin's thickness of the outer surface (and the voxel that places it), or
            continue
                            # past the base's surface: the skin's or the base's silicone, not the filling's
        warnings.append("silicone in the filling near voxel "
                        f"{np.round(centre + offset).astype(int).tolist()} holds a small inclusion's volume "
                        "but is not round: not labelled an inclusion")
    inclusion, shapes = local_surface(bodies & ~run_on, frac, deep & ~pillar, spacing, RIM_VOXELS * voxel_mm,
                                       inclusion_shape, beyond, blurred)
    inclusion |= junctions(inclusion, pillar, spacing, shapes)
    pillar &= ~inclusion
    for i in missing:
        centre = (np.round(ndimage.center_of_mass(inc_ids == i)).astype(int) + offset).tolist()
        warnings.append(f"pillar not connected: no pillar found under the inclusion near voxel {centre}")
    inner = (slice(1, -1),) * 3
    pillar_full[box], inclusion_full[box] = pillar[inner], inclusion[inner]
    for row in shapes:
        row["centre_index"] = [float(c + o) for c, o in zip(row["centre_index"], offset)]
    return (pillar_full, inclusion_full, warnings, shapes,
            None if base is None else base.shifted(-offset, spacing),
            [post.shifted(-offset, spacing) for post in posts])
