"""Uncertainty-guided palpation: where to touch next.

LESS's uncertainty is local: a pixel's entropy only changes when touches land near it (within a
particle's receptive field plus half a patch). So the value of touching at (x, y) is estimated as the
entropy that lies within ``radius_mm`` of it (the disc a touch resolves), in nats x mm^2. Touches are
chosen greedily: take the best candidate inside the phantom outline, assume its disc is resolved
(its entropy set to 0), forbid candidates within ``exclusion_mm`` of it so suggestions spread apart,
and repeat. This is the standard greedy rule for covering the most uncertainty with K discs.

For a 3D image the map that is covered is the column mean of the entropy (a touch informs a whole
column). Candidates are pixel centres of the image grid inside the outline shrunk by ``margin_mm``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesscli.errors import DataError
from lesscli.io.labels import INCLUSION
from lesscli.types import ImageGrid

DEFAULT_MARGIN_MM = 3.0       # suggestions keep the pad centre this far inside the outline
DEFAULT_WIDTH_MM = 60.0       # octagon across flats when no label volume gives the footprint
PROB_FLOOR = 1e-12            # floor inside log(p) (0 * log 0 = 0)


def class_entropy(probs: np.ndarray) -> np.ndarray:
    """(C, ...) probabilities -> (...) Shannon entropy over the classes, nats."""
    p = np.asarray(probs, np.float64)
    return -(p * np.log(np.clip(p, PROB_FLOOR, None))).sum(axis=0)


def inclusion_entropy(probs: np.ndarray) -> np.ndarray:
    """(C, ...) probabilities -> (...) binary entropy of inclusion vs the rest, nats (max ln 2 at p = 0.5)."""
    p = np.clip(np.asarray(probs[INCLUSION], np.float64), PROB_FLOOR, 1.0 - PROB_FLOOR)
    return -(p * np.log(p) + (1.0 - p) * np.log1p(-p))


# what "uncertainty" the guide covers: every class, or only whether a pixel is inclusion
UNCERTAINTY = {"entropy": class_entropy, "inclusion": inclusion_entropy}


@dataclass
class GuideOptions:
    """How to choose touches.

    Attributes:
        k: number of touch locations.
        radius_mm: radius of the disc a touch resolves (default: the model's receptive field).
        exclusion_mm: minimum distance between suggestions (default: ``radius_mm``).
        margin_mm: distance kept from the phantom outline.
        score: key of ``UNCERTAINTY``: class entropy, or the inclusion-vs-rest entropy.
    """

    k: int = 5
    radius_mm: float | None = None
    exclusion_mm: float | None = None
    margin_mm: float = DEFAULT_MARGIN_MM
    score: str = "entropy"


def pixel_centres_mm(grid: ImageGrid) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) x and y of every pixel centre, mm (columns follow x, rows follow y)."""
    _, h, w = grid.shape
    x = grid.origin_mm[2] + grid.spacing_mm[2] * np.arange(w)
    y = grid.origin_mm[1] + grid.spacing_mm[1] * np.arange(h)
    return np.meshgrid(x, y)


def octagon_mask(grid: ImageGrid, width_mm: float, margin_mm: float) -> np.ndarray:
    """(H, W) bool: pixel centres inside the phantom octagon (``width_mm`` across flats) shrunk by a
    margin."""
    from lesscli.phantom.geometry import Phantom

    inner = width_mm - 2.0 * margin_mm
    if inner <= 0:
        raise DataError(f"margin {margin_mm} mm leaves no room inside a {width_mm} mm phantom")
    x, y = pixel_centres_mm(grid)
    return Phantom(name="outline", width_mm=inner).inside_outline(x, y)


def footprint_mask(labels: np.ndarray, grid: ImageGrid, margin_mm: float) -> np.ndarray:
    """(H, W) bool: columns where the label volume (D, H, W) has any non-background voxel, eroded by a
    margin."""
    from scipy import ndimage

    body = (labels != 0).any(axis=0)
    if margin_mm <= 0:
        return body
    return ndimage.distance_transform_edt(body, sampling=grid.spacing_mm[1:]) > margin_mm


def disc_kernel(radius_mm: float, spacing_mm: tuple[float, float]) -> np.ndarray:
    """(2a+1, 2b+1) float64 indicator of a disc of ``radius_mm`` on pixels of (dy, dx) mm."""
    ry, rx = (int(np.floor(radius_mm / s)) for s in spacing_mm)
    yy, xx = np.mgrid[-ry:ry + 1, -rx:rx + 1]
    return ((yy * spacing_mm[0]) ** 2 + (xx * spacing_mm[1]) ** 2 <= radius_mm**2).astype(np.float64)


def suggest_touches(entropy: np.ndarray, grid: ImageGrid, allowed: np.ndarray, opts: GuideOptions,
                    receptive_field_mm: float) -> list[dict]:
    """Greedy K touch locations that cover the most remaining entropy.

    Args:
        entropy: (D, H, W) or (H, W) per-pixel entropy, nats.
        grid: geometry of the image.
        allowed: (H, W) bool candidate pixels (inside the outline).
        opts: K, radii and margin.
        receptive_field_mm: the model's receptive-field radius (default disc radius).

    Returns:
        Up to K records ``{rank, x_mm, y_mm, entropy_covered_nats_mm2, mean_entropy_nats}``, best first;
        fewer when the exclusion zones use up every allowed pixel.
    """
    from scipy.signal import fftconvolve

    ent = np.asarray(entropy, np.float64)
    ent = ent.mean(axis=0) if ent.ndim == 3 else ent
    radius = float(opts.radius_mm or receptive_field_mm)
    if not np.isfinite(radius) or radius <= 0:
        raise DataError(f"touch radius must be a finite positive number of mm, got {radius} "
                        "(set --radius-mm for models without local receptive fields)")
    exclusion = float(opts.exclusion_mm if opts.exclusion_mm is not None else radius)
    spacing = (float(grid.spacing_mm[1]), float(grid.spacing_mm[2]))
    kernel = disc_kernel(radius, spacing)
    pixel_area = spacing[0] * spacing[1]
    x, y = pixel_centres_mm(grid)
    free = np.asarray(allowed, bool).copy()
    remaining = ent.copy()
    rows = []
    for rank in range(1, opts.k + 1):
        if not free.any():
            break
        covered = fftconvolve(remaining, kernel, mode="same")
        score = np.where(free, covered, -np.inf)
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        d2 = (x - x[i, j]) ** 2 + (y - y[i, j]) ** 2
        disc = d2 <= radius**2
        rows.append({"rank": rank, "x_mm": float(x[i, j]), "y_mm": float(y[i, j]),
                     "entropy_covered_nats_mm2": float(max(covered[i, j], 0.0) * pixel_area),
                     "mean_entropy_nats": float(ent[disc].mean())})
        remaining[disc] = 0.0
        free &= d2 >= exclusion**2
    return rows


@dataclass
class Guidance:
    """Suggestions for one scan and what they were computed from.

    Attributes:
        rows: the suggestion records (see :func:`suggest_touches`).
        labels: (D, H, W) predicted codes; entropy: (D, H, W) the covered uncertainty (``opts.score``),
        nats; allowed: (H, W) candidate mask.
        grid: image geometry; touches_xy_mm: (n, 2) pad x, y of the partial scan's samples.
    """

    rows: list[dict]
    labels: np.ndarray
    entropy: np.ndarray
    allowed: np.ndarray
    grid: ImageGrid
    touches_xy_mm: np.ndarray


def guide_scan(imager, ckpt: dict, scans, s: int, opts: GuideOptions, width_mm: float | None = None,
               threshold: float | None = None, min_volume_mm3: float | None = None,
               smooth_mm: float | None = None) -> Guidance:
    """Image scan ``s`` of a (partial) scan set and suggest its next touches.

    The candidate region is the scan's label footprint when it has a label volume and ``width_mm``
    is None, else the octagon of ``width_mm`` (default 60 mm), both shrunk by ``opts.margin_mm``.
    """
    from lesscli.data.image_labels import AUTO_SLICE
    from lesscli.infer.predict import labelling_rule, scan_grid
    from lesscli.infer.stream import StreamingImager
    from lesscli.models.registry import lookup

    image_cfg = ckpt["config"]["image"]
    grid, _ = scan_grid(scans, s, int(image_cfg["dim"]), int(image_cfg.get("slice", AUTO_SLICE)), imager.grid)
    stream = StreamingImager(imager, ckpt["norm_stats"], grid)
    steps = scans.scan_steps(s)
    stream.prime(scans.pose[steps], scans.force[steps])
    label = scans.label_of(s)
    if label is not None and width_mm is None:
        allowed = footprint_mask(label.data, grid, opts.margin_mm) if label.data.shape[1:] == grid.shape[1:] \
            else octagon_mask(grid, DEFAULT_WIDTH_MM, opts.margin_mm)
    else:
        allowed = octagon_mask(grid, width_mm or DEFAULT_WIDTH_MM, opts.margin_mm)
    probs = stream.probs()
    ent = stream.entropy() if opts.score == "entropy" else lookup(UNCERTAINTY, opts.score,
                                                                  "guide score")(probs)
    rows = suggest_touches(ent, grid, allowed, opts, stream.radius_mm)
    labelling = labelling_rule(image_cfg, threshold, min_volume_mm3, smooth_mm)
    return Guidance(rows, labelling.labels(probs, grid.spacing_mm), ent, allowed, grid,
                    np.asarray(scans.pose[steps][:, :2], np.float64))
