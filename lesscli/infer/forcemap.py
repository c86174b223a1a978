"""Classical force-map imager: the reference every learned imaging result is reported against.

Per poke, the deepest step gives each taxel a stiffness sample (normal force over its own indentation in
the scan's surface frame, :mod:`lesscli.data.surface`; N/mm) at its x-y. The samples are flat-fielded
and detrended over the contact area and smoothed onto a grid of ``GRID_MM`` cells (or the calibration's own)
(:func:`stiffness_map`); each region above ``threshold`` robust spreads is one inclusion, sized and placed in
depth by calibrated rules (:func:`detect`, :func:`spheres`). :func:`calibrate` fits only what a classical
pipeline calibrates, on the training label volumes: the smoothing width, the threshold, the size and depth
rules and the class prior per depth (:func:`scan_probs`). numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from lesscli.errors import DataError
from lesscli.io.labels import INCLUSION, INSERT, LabelVolume
from lesscli.metrics.masks import centroid_mm, confusion, f1_from, size_mm
from lesscli.robust import robust_sigma
from lesscli.sim.kinematics import pad_to_world

MODEL = "forcemap"      # config["model"] of its checkpoints and meta["model"] of its predictions
EPS_DEPTH_MM = 0.05     # taxels indented less than this are grazing: no stiffness sample
FLAT_MIN_POKES = 5      # a taxel's flat-field gain needs this many valid samples
GRID_MM = 0.5           # force-map cell size
COVER_FRAC = 0.1        # covered: weight sum >= this fraction of one lone sample's peak weight
CONTACT_FRAC = 0.75     # contact area: smoothed stiffness >= this fraction of the covered median
SPREAD_FLOOR = 0.01     # robust spread never below this fraction of the median stiffness (flat maps)
EDGE_VOXELS = 0.5       # logistic scale of the sphere surface, in-plane voxels
SIGMAS_MM = (1.5, 2.0, 3.0, 4.0)                      # smoothing widths tried by calibration
THRESHOLDS = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0)  # thresholds tried, robust spreads


@dataclass
class Touches:
    """Stiffness samples of one scan: ``xy_mm`` (n, 2) phantom frame, ``stiffness_n_per_mm`` (n,),
    ``taxel`` (n,) the taxel index of each sample."""

    xy_mm: np.ndarray
    stiffness_n_per_mm: np.ndarray
    taxel: np.ndarray


@dataclass
class StiffnessMap:
    """A smoothed, detrended stiffness map on cells (H, W) whose [0, 0] centre is at ``origin_xy_mm``.

    ``residual`` (H, W) N/mm after the trend, ``contact`` (H, W) bool, ``spread`` its robust SD.
    """

    origin_xy_mm: np.ndarray
    residual: np.ndarray
    contact: np.ndarray
    spread: float
    cell_mm: float = GRID_MM


@dataclass
class Calibration:
    """What :func:`calibrate` fits (plain values).

    A region of area A becomes a sphere of diameter ``d = diameter_mm + diameter_per_mm * sqrt(A)``
    (clipped to ``diameter_range_mm``) centred ``depth_mm + depth_per_diameter * d`` below the
    surface; ``prior`` (2, Z, 3) holds the class frequencies at the depths ``prior_z_mm`` (Z,).
    """

    sigma_mm: float
    threshold: float
    diameter_mm: float
    diameter_per_mm: float
    diameter_range_mm: list
    depth_mm: float
    depth_per_diameter: float
    prior_z_mm: list
    prior: list
    grid_mm: float = GRID_MM     # force-map cell (older checkpoints: the default)


def taxel_layout(meta: dict, name: str) -> np.ndarray:
    """(T, 2) taxel x-y in the pad frame from scan-set meta; DataError naming ``name`` without one."""
    xy = (meta.get("sensor") or {}).get("taxel_xy_mm")
    if not xy:
        raise DataError(f"{name}: meta has no sensor layout ('sensor.taxel_xy_mm'); "
                        "the force map needs the taxel positions")
    return np.asarray(xy, np.float64).reshape(-1, 2)


def scan_touches(scans, s: int, taxel_xy_mm: np.ndarray, steps: int | None = None) -> Touches:
    """Stiffness samples of the deepest step of each poke of scan ``s`` (its first ``steps`` steps)."""
    sl = scans.scan_steps(s)
    n = sl.stop - sl.start if steps is None else min(steps, sl.stop - sl.start)
    toff = scans.scan_traj_offsets()
    bounds = np.clip(scans.traj_offsets[toff[s]:toff[s + 1] + 1] - sl.start, 0, n)
    pose, force = scans.pose[sl.start:sl.start + n], scans.force[sl.start:sl.start + n]
    traj = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))
    order = np.lexsort((pose[:, 2], traj))
    deepest = order[np.unique(traj[order], return_index=True)[1]]
    world = pad_to_world(pose[deepest], taxel_xy_mm)                 # (P, T, 3)
    depth = -world[..., 2]
    ok = depth > EPS_DEPTH_MM
    stiff = force[deepest, :, 2].astype(np.float64) / np.where(ok, depth, 1.0)
    return Touches(world[..., :2][ok], stiff[ok], np.nonzero(ok)[1])


def taxel_gains(ratio: np.ndarray, taxel: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(n,) flat-field gain of each sample's taxel: the taxel's median ``ratio`` (sample / trend) over
    its ``use`` samples, relative to the median taxel. Taxels with fewer than ``FLAT_MIN_POKES``
    such samples, or a median <= 0, keep gain 1."""
    gain = np.zeros(int(taxel.max()) + 1)
    for t in np.flatnonzero(np.bincount(taxel[use], minlength=len(gain)) >= FLAT_MIN_POKES):
        gain[t] = np.median(ratio[use & (taxel == t)])
    good = gain > 0
    return np.where(good, gain / np.median(gain[good]), 1.0)[taxel] if good.any() else np.ones(len(taxel))


def _quadratic_fit(basis: np.ndarray, values: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(n,) least-squares quadratic trend at every sample, fitted on the ``use`` samples."""
    return basis @ np.linalg.lstsq(basis[use], values[use], rcond=None)[0]


def _smooth(cells: np.ndarray, values: np.ndarray, shape: tuple, sig: float) -> tuple[np.ndarray, np.ndarray]:
    """Normalised convolution of (n,) samples at (n, 2) x, y cells: ((H, W) map, (H, W) covered)."""
    num, den = np.zeros(shape), np.zeros(shape)
    np.add.at(num, (cells[:, 1], cells[:, 0]), values)
    np.add.at(den, (cells[:, 1], cells[:, 0]), 1.0)
    num, den = ndimage.gaussian_filter(num, sig), ndimage.gaussian_filter(den, sig)
    covered = den >= COVER_FRAC / (2 * np.pi * sig**2)
    return np.where(covered, num / np.where(covered, den, 1.0), 0.0), covered


def stiffness_map(touches: Touches, sigma_mm: float, cell_mm: float = GRID_MM) -> StiffnessMap | None:
    """Smoothed stiffness, its contact area and the detrended map; None without samples.

    Smoothing is normalised convolution (Gaussian-weighted average sum(w v) / sum(w)); cells with little
    weight are not covered, and covered cells softer than ``CONTACT_FRAC`` of the median are off the
    insert (the contact area).

    The quadratic trend is fitted to the samples inside the contact area; each taxel is flat-fielded
    by its median ratio to that trend (per-taxel gain, the pad's own pressure profile), the trend is
    fitted again and subtracted from every sample before the residuals are smoothed, so a purely
    quadratic field leaves an exactly flat map (smoothing first would leave the smoothing's own bias
    at the map's edges as structure).
    """
    v = touches.stiffness_n_per_mm
    if not len(v):
        return None
    sig = sigma_mm / cell_mm
    lo = touches.xy_mm.min(axis=0) - 3 * sigma_mm
    cells = np.round((touches.xy_mm - lo) / cell_mm).astype(int)      # (n, 2) x, y cell index
    shape = tuple(cells[:, ::-1].max(axis=0) + int(np.ceil(3 * sig)) + 1)
    value, covered = _smooth(cells, v, shape, sig)
    level = float(np.median(value[covered]))
    contact = covered & (value >= CONTACT_FRAC * level)
    inside = contact[cells[:, 1], cells[:, 0]]
    if level <= 0 or inside.sum() < 6:
        return StiffnessMap(lo, np.zeros(shape), np.zeros(shape, bool), 1.0, cell_mm)
    x, y = ((touches.xy_mm - touches.xy_mm.mean(axis=0)) / (cell_mm * max(shape))).T
    basis = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)
    trend = _quadratic_fit(basis, v, inside)
    v = v / taxel_gains(v / np.where(trend > 0, trend, np.inf), touches.taxel, inside & (trend > 0))
    residual = np.where(contact, _smooth(cells, v - _quadratic_fit(basis, v, inside), shape, sig)[0], 0.0)
    r = residual[contact]
    spread = max(robust_sigma(r), SPREAD_FLOOR * level)
    return StiffnessMap(lo, residual, contact, spread, cell_mm)


def detect(fmap: StiffnessMap | None, threshold: float) -> np.ndarray:
    """(k, 3) regions above threshold: x, y mm of the excess-weighted centroid and sqrt(area) mm."""
    if fmap is None:
        return np.zeros((0, 3))
    excess = np.where(fmap.contact, fmap.residual - threshold * fmap.spread, 0.0)
    regions, k = ndimage.label(excess > 0)
    if not k:
        return np.zeros((0, 3))
    yx = np.array(ndimage.center_of_mass(excess, regions, range(1, k + 1))).reshape(-1, 2)
    side = np.sqrt(np.bincount(regions.ravel(), minlength=k + 1)[1:]) * fmap.cell_mm
    return np.column_stack([fmap.origin_xy_mm + yx[:, ::-1] * fmap.cell_mm, side])


def spheres(regions: np.ndarray, cal: Calibration) -> np.ndarray:
    """(k, 3) regions -> (k, 4) spheres x, y, z mm (phantom frame) and diameter mm."""
    d = np.clip(cal.diameter_mm + cal.diameter_per_mm * regions[:, 2], *cal.diameter_range_mm)
    return np.column_stack([regions[:, :2], -(cal.depth_mm + cal.depth_per_diameter * d), d])


def signed_distance_mm(balls: np.ndarray, shape, origin_mm, spacing_mm) -> np.ndarray:
    """(D, H, W) distance to the nearest surface of (k, 4) ``balls`` (negative inside, +inf if none), mm."""
    z, y, x = (np.asarray(origin_mm)[a] + np.asarray(spacing_mm)[a] * np.arange(shape[a]) for a in range(3))
    out = np.full(tuple(shape), np.inf)
    for cx, cy, cz, d in balls:
        d2 = (z[:, None, None] - cz) ** 2 + (y[None, :, None] - cy) ** 2 + (x[None, None, :] - cx) ** 2
        out = np.minimum(out, np.sqrt(d2) - d / 2)
    return out


def touched_xy(fmap: StiffnessMap | None, shape, origin_mm, spacing_mm) -> np.ndarray:
    """(H, W) bool: voxel columns whose x-y lies in the map's contact area."""
    if fmap is None:
        return np.zeros(tuple(shape[1:]), bool)
    y = (origin_mm[1] + spacing_mm[1] * np.arange(shape[1]) - fmap.origin_xy_mm[1]) / fmap.cell_mm
    x = (origin_mm[2] + spacing_mm[2] * np.arange(shape[2]) - fmap.origin_xy_mm[0]) / fmap.cell_mm
    (h, w), iy, ix = fmap.contact.shape, np.round(y).astype(int), np.round(x).astype(int)
    inside = ((iy >= 0) & (iy < h))[:, None] & ((ix >= 0) & (ix < w))[None, :]
    return fmap.contact[np.clip(iy, 0, h - 1)][:, np.clip(ix, 0, w - 1)] & inside


def scan_probs(cal: Calibration, touches: Touches, shape, origin_mm, spacing_mm) -> np.ndarray:
    """Class probabilities (4, D, H, W) float32 of one scan on a label grid.

    The touched prior where the scan touched and the overall one elsewhere, so untouched voxels stay
    uncertain and a larger insert (the ``large`` set) is insert wherever it was touched. The inclusion
    probability is a logistic in the signed distance to the nearest sphere surface, ``EDGE_VOXELS``
    in-plane voxels wide.
    """
    origin_mm, spacing_mm = np.asarray(origin_mm, np.float64), np.asarray(spacing_mm, np.float64)
    fmap = stiffness_map(touches, cal.sigma_mm, cal.grid_mm)
    sd = signed_distance_mm(spheres(detect(fmap, cal.threshold), cal), shape, origin_mm, spacing_mm)
    q = 1.0 / (1.0 + np.exp(np.clip(sd / (EDGE_VOXELS * spacing_mm[1:].mean()), -50, 50)))
    z = origin_mm[0] + spacing_mm[0] * np.arange(shape[0])
    zi = np.abs(z[:, None] - np.asarray(cal.prior_z_mm)[None]).argmin(axis=1)
    prior = np.asarray(cal.prior)[:, zi]                               # (2, D, 3)
    touched = touched_xy(fmap, shape, origin_mm, spacing_mm)
    rest = np.where(touched[None, None], prior[1][..., None, None], prior[0][..., None, None])  # (D, 3, H, W)
    probs = np.concatenate([rest.transpose(1, 0, 2, 3) * (1 - q), q[None]])
    return probs.astype(np.float32)


def inclusions(label: LabelVolume) -> tuple[list[np.ndarray], list[float]]:
    """Centroids (z, y, x mm) and volume-equivalent diameters (mm) of a label volume's inclusions."""
    parts, k = ndimage.label(label.data == INCLUSION)
    masks = [parts == i for i in range(1, k + 1)]
    diam = [float((6 / np.pi * size_mm(m, np.prod(label.spacing_mm))) ** (1 / 3)) for m in masks]
    return [centroid_mm(m, label.origin_mm, label.spacing_mm) for m in masks], diam


def _class_prior(maps: list, targets: list[LabelVolume]) -> tuple[list, list]:
    """Per-depth background/insert/pillar frequencies (inclusion counted as insert), Laplace-smoothed:
    (Z,) depths and (2, Z, 3) tables over all voxels and over the touched ones."""
    z_all = np.unique(np.round(np.concatenate([t.axes_mm()[0] for t in targets]), 6))
    counts = np.ones((2, len(z_all), 3))
    for fmap, t in zip(maps, targets):
        codes = np.where(t.data == INCLUSION, INSERT, t.data).astype(int)
        touched = np.broadcast_to(touched_xy(fmap, t.shape, t.origin_mm, t.spacing_mm), t.shape)
        zi = np.broadcast_to(np.searchsorted(z_all, np.round(t.axes_mm()[0], 6))[:, None, None], t.shape)
        for row, sel in ((0, np.ones(t.shape, bool)), (1, touched)):
            np.add.at(counts[row], (zi[sel], codes[sel]), 1.0)
    return z_all.tolist(), (counts / counts.sum(axis=-1, keepdims=True)).tolist()


def _micro_f1(regions: list[np.ndarray], cal: Calibration, targets: list[LabelVolume]) -> float:
    """Micro inclusion F1 over the targets of the spheres ``cal`` makes of each scan's regions."""
    counts = np.zeros(3, np.int64)
    for reg, t in zip(regions, targets):
        pred = signed_distance_mm(spheres(reg, cal), t.shape, t.origin_mm, t.spacing_mm) <= 0
        counts += confusion(pred, t.data == INCLUSION)
    return float(f1_from(*(int(c) for c in counts)) or 0.0)


def _size_rules(regions: list[np.ndarray], truths: list, mean_mm: float) -> list[tuple[float, float]]:
    """Candidate (intercept mm, slope per mm of sqrt(area)) size rules: the training mean, and a
    least-squares line through (sqrt(area), true diameter) of the regions centred inside a true
    inclusion's radius (with at least 3 such pairs)."""
    pairs = []
    for reg, (centres, diams) in zip(regions, truths):
        for c, d in zip(centres, diams):
            dist = np.linalg.norm(reg[:, :2] - c[[2, 1]], axis=1)
            if len(reg) and dist.min() < d / 2:
                pairs.append((reg[dist.argmin(), 2], d))
    if len(pairs) < 3 or np.ptp([p[0] for p in pairs]) == 0:
        return [(mean_mm, 0.0)]
    slope, intercept = np.polyfit(*np.array(pairs).T, 1)
    return [(mean_mm, 0.0), (float(intercept), float(slope))]


def calibrate(touches: list[Touches], labels: list[LabelVolume], targets: list[LabelVolume],
              name: str = "scan set", sigmas_mm: tuple[float, ...] = SIGMAS_MM,
              grid_mm: float = GRID_MM) -> tuple[Calibration, float]:
    """Fit a :class:`Calibration` on training scans.

    Each connected inclusion component of a label is one inclusion (its centroid, its volume-equivalent
    diameter). Fitted: the smoothing width (of ``sigmas_mm``) and the threshold (grid search for the best
    micro inclusion F1), a size rule (the mean diameter, or a line in the square root of the region area
    when that scores better), a depth rule (least-squares line of the centre's depth in the diameter; the
    mean depth when all diameters agree) and the class prior: per depth, the frequencies of
    background/insert/pillar over all voxels and over the touched voxels (x-y in the contact area), all on
    a force map of ``grid_mm`` cells.

    Args:
        touches: per scan, its stiffness samples.
        labels: per scan, its 3D label volume (inclusion diameters and depths).
        targets: per scan, the volume scored (3D: the label; 2D: its slice as a depth-1 volume).
        name: the scan set's name for errors.
        sigmas_mm: the smoothing widths tried (one: the width fixed).
        grid_mm: the force map's cell.

    Returns:
        The calibration and its training micro inclusion F1.
    """
    truths = [inclusions(v) for v in labels]
    depth = np.array([-c[0] for cs, _ in truths for c in cs])
    diam = np.array([d for _, ds in truths for d in ds])
    if not len(diam):
        raise DataError(f"{name}: no training label volume holds an inclusion; nothing to calibrate on")
    slope, icept = np.polyfit(diam, depth, 1) if np.ptp(diam) > 0 else (0.0, float(depth.mean()))
    base = Calibration(0.0, 0.0, float(diam.mean()), 0.0, [float(diam.min()), float(diam.max())],
                       float(icept), float(slope), [], [], float(grid_mm))
    best, best_f1 = base, -1.0
    for sigma in sigmas_mm:
        maps = [stiffness_map(t, sigma, grid_mm) for t in touches]
        for thr in THRESHOLDS:
            regions = [detect(m, thr) for m in maps]
            for a, b in _size_rules(regions, truths, base.diameter_mm):
                cand = replace(base, sigma_mm=sigma, threshold=thr, diameter_mm=a, diameter_per_mm=b)
                f1 = _micro_f1(regions, cand, targets)
                if f1 > best_f1:
                    best, best_f1 = cand, f1
    best.prior_z_mm, best.prior = _class_prior([stiffness_map(t, best.sigma_mm, grid_mm) for t in touches],
                                               targets)
    return best, best_f1


def calibration_from_dict(data: dict, name: str) -> Calibration:
    """A Calibration from a checkpoint's ``config['forcemap']``; DataError naming ``name`` when malformed."""
    try:
        defaults = {"grid_mm": GRID_MM}                 # fields older checkpoints lack
        cal = Calibration(**{k: data[k] if k in data or k not in defaults else defaults[k]
                             for k in Calibration.__dataclass_fields__})
        prior = np.asarray(cal.prior, np.float64)
        scalars = np.asarray([cal.sigma_mm, cal.threshold, cal.diameter_mm, cal.diameter_per_mm, cal.depth_mm,
                              cal.depth_per_diameter, cal.grid_mm, *cal.diameter_range_mm, *cal.prior_z_mm],
                             np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{name}: malformed force-map calibration ({type(exc).__name__}: {exc})") from None
    if prior.shape != (2, len(cal.prior_z_mm), 3) or not cal.prior_z_mm or len(cal.diameter_range_mm) != 2 \
            or not np.isfinite(scalars).all() or cal.sigma_mm <= 0 or cal.grid_mm <= 0:
        raise DataError(f"{name}: malformed force-map calibration (prior shape, diameter range or values)")
    return cal
