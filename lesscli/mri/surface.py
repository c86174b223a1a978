"""Each inclusion's surface, drawn from its body: re-thresholded with its local contrast, or its fitted ball.

The opening that finds an inclusion (:mod:`lesscli.mri.morphology`) leaves its surface where the global
threshold put it, rough with noise. :func:`local_surface` draws it again at the level where a blurred ball's
surface lies (below half-way on a curved surface: the blur spreads a small body's silicone outwards), with
the blur and radius fitted to the body's own profile away from the pillars and the base's silicone
(:func:`lesscli.mri.ball.fitted_ball`). Where a pillar meets its inclusion, :func:`junctions` gives the
inclusion back the pillar's voxels inside its sphere.
"""

from __future__ import annotations

import math

import numpy as np

from lesscli.mri.ball import fitted_ball

JUNCTION_STEPS = 4
# an inclusion whose blurred ball fits its voxels this close to the noise is that ball
BALL_MISFIT = 1.25


def local_surface(bodies: np.ndarray, fraction: np.ndarray, allowed: np.ndarray, spacing: np.ndarray,
                   reach_mm: float, shape: str = "auto", unfitted: np.ndarray | None = None,
                   blurred: np.ndarray | None = None) -> np.ndarray:
    """Each body's surface between its own interior level and the filling's level around it.

    The opening leaves a body's surface where the global threshold put it, up to the roughness that
    noise gives; here each inclusion is re-thresholded with its local contrast, within ``reach_mm`` of it,
    at the surface level of a blurred ball fitted to it (:func:`fitted_ball`). ``shape``: "image" keeps
    that surface; "ball" takes the fitted ball's voxels in ``allowed`` instead, all of them (the opening
    can leave a small inclusion's body a voxel or more inside its ball all round, and a ball drawn only
    within ``reach_mm`` of the body lost that rim: seed 1068 of the family, a 7.6 mm inclusion at 1.2 mm
    voxels, Dice 0.87 instead of 0.99); "auto" takes the ball where it fits the
    voxels near the body as well as the scan's noise allows (:attr:`Ball.misfit` at most
    ``BALL_MISFIT``: the noise, not the shape, is then what separates them) and the image's surface
    elsewhere (a body that is not a ball fits worse). ``unfitted``: voxels no ball is fitted to (the base's
    silicone), None: none; neither a body's nor its image's surface takes them (a body can run on through a
    short post into the base). ``blurred``: voxels no ball is fitted to either, but which either surface
    may take (the blur of a post beside its inclusion, and of the base's surface on the filling's side).

    Returns:
        (inclusion mask, one dict per body: ``shape`` "ball" or "image", ``centre_index`` (the fitted
        ball's centre, else the body's centroid, in voxel indices), ``ball_diameter_mm`` and
        ``ball_misfit`` (None where no ball was fitted)).
    """
    from scipy import ndimage

    comps, _n = ndimage.label(bodies)
    out = np.zeros(bodies.shape, dtype=bool)
    base = np.zeros(bodies.shape, dtype=bool) if unfitted is None else unfitted
    shapes = []
    for i, sl in enumerate(ndimage.find_objects(comps), start=1):
        own = (comps == i) & ~base
        fit = fitted_ball(own, fraction, allowed, spacing, sl, reach_mm,
                          base if blurred is None else base | blurred)
        if fit is None:
            out |= own
            shapes.append({"shape": "image", "centre_index": list(ndimage.center_of_mass(own)),
                           "ball_diameter_mm": None, "ball_misfit": None})
            continue
        ball = fit.radius_mm > 0 and (shape == "ball" or (shape == "auto" and fit.misfit <= BALL_MISFIT))
        out[fit.box] |= (fit.inside() & allowed[fit.box]) if ball else \
            fit.near & (fraction[fit.box] > fit.level) & ~base[fit.box]
        shapes.append({"shape": "ball" if ball else "image", "centre_index": list(fit.centre_mm / spacing),
                       "ball_diameter_mm": 2 * fit.radius_mm if fit.radius_mm > 0 else None,
                       "ball_misfit": fit.misfit if math.isfinite(fit.misfit) else None})
    return out, shapes


def junctions(bodies: np.ndarray, pillar: np.ndarray, spacing: np.ndarray, shapes: list[dict]) -> np.ndarray:
    """The ``pillar`` voxels inside each body's sphere: its fitted ball where it was drawn as one, else the
    sphere of its centroid and volume.

    Where a pillar meets an inclusion the image shows one silicone body, and the pillar is drawn up to the
    inclusion's centre; the inclusion takes back the voxels inside it. A body drawn as its fitted ball
    (``shapes``, :func:`local_surface`) is that ball, cap included, as the phantom's sphere stands on its
    post; another body's surface is continued across the pillar as the sphere of the same volume and
    centre (the body plus the pillar voxels inside that sphere, found by a few fixed-point steps).
    """
    from scipy import ndimage

    comps, _n = ndimage.label(bodies)
    out = np.zeros(bodies.shape, dtype=bool)
    cand = np.argwhere(pillar)
    if not len(cand):
        return out
    cand_mm, voxel_mm3 = cand * spacing, float(np.prod(spacing))
    balls = {}              # component -> (centre, radius) of the ball it was drawn as
    body = np.argwhere(comps)
    for row in shapes:
        # the component nearest its centre (the pillar runs through it)
        if row["shape"] == "ball" and len(body):
            centre = np.asarray(row["centre_index"]) * spacing
            nearest = body[np.argmin(np.sum((body * spacing - centre) ** 2, axis=1))]
            balls[int(comps[tuple(nearest)])] = (centre, 0.5 * row["ball_diameter_mm"])
    for i, sl in enumerate(ndimage.find_objects(comps), start=1):
        if i in balls:
            centre, radius = balls[i]
            inside = np.sum((cand_mm - centre) ** 2, axis=1) <= radius ** 2
        else:
            own_mm = (np.argwhere(comps[sl] == i) + [s.start for s in sl]) * spacing
            inside = np.zeros(len(cand), dtype=bool)
            for _ in range(JUNCTION_STEPS):
                centre = (own_mm.sum(axis=0) + cand_mm[inside].sum(axis=0)) / (len(own_mm) + inside.sum())
                radius = (3.0 * (len(own_mm) + inside.sum()) * voxel_mm3 / (4 * math.pi)) ** (1 / 3)
                inside = np.sum((cand_mm - centre) ** 2, axis=1) <= radius ** 2
        out[tuple(cand[inside].T)] = True
    return out
