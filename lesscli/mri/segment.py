"""MRI volume -> labels (0 background, 1 insert, 2 pillar, 3 inclusion), in 3D and physical units.

The pipeline (:func:`segment`) normalises and smooths the intensities, corrects the bias field
(:mod:`lesscli.mri.bias`), thresholds three classes (air, dark and bright tissue) half-way between their
multi-Otsu levels (the 50 % partial-volume surfaces), takes the largest object that does not cross the
scan from face to face (a container or bath is background) as the insert, calls its minority tissue
silicone (the filling is hydrogel, so either contrast works), and splits the silicone into inclusions,
pillars and skin (:mod:`lesscli.mri.morphology`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lesscli.errors import DataError
from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, PILLAR
from lesscli.mri.pillar import BaseSurface, Post
from lesscli.robust import robust_sigma

NORM_PERCENTILE = 99.5
MIN_SHAPE = 8                   # voxels per axis
MIN_INSERT_MM3 = 1000.0         # smaller objects are not an insert
MIN_CONTRAST = 4.0              # (insert median - air median) / air spread (robust sigma)
SPREAD_EPS = 1e-6
HIST_SAMPLES = 400_000          # voxels used for histograms and fits
SAMPLE_SEED = 0                 # fixed subsampling: the segmentation is deterministic
SURFACE_BAND_VOXELS = 1.5       # the outer surface is re-decided this close to it
SURFACE_LAYER_VOXELS = 1.0      # the tissue level is read in a layer from this deep (past the partial volume)
SURFACE_LAYER_MM = 1.0          # ... this thick (at least one largest voxel)
SURFACE_SIGMA_MM = 3.0          # ... averaged along the surface over this
SURFACE_MIN_WEIGHT = 0.01       # band voxels with no layer nearby keep the global decision
RICE_BISECTIONS = 40            # inverting the Rice mean for a tissue's signal
SMOOTH_VOXELS = 0.6             # the denoising's default sigma, in finest voxels


@dataclass(frozen=True)
class SegmentParams:
    """Knobs of :func:`segment` (lengths in mm).

    Attributes:
        pillar_max_diameter_mm: thickest pillar; the inclusion-finding ball is thicker than this.
        skin_max_thickness_mm: thickest skin; the ball is also thicker than this.
        smooth_mm: Gaussian sigma of the denoising; None = SMOOTH_VOXELS (0.6) x the finest voxel size.
        bias_degree: polynomial degree of the log bias field (0 = no correction).
        inclusion_shape: "auto" (an inclusion is its fitted ball where that fits within the noise, else
            the image's surface), "image" or "ball" (always).
        pillar_diameter_mm: the posts' diameter as cast, where it is known (the mould's): each post is
            still found, placed and ended from the scan, but drawn this wide (its measured diameter is
            kept, :attr:`lesscli.mri.pillar.Post.measured_radius_mm`); None: drawn as measured.
    """

    pillar_max_diameter_mm: float = 4.5
    skin_max_thickness_mm: float = 3.0
    smooth_mm: float | None = None
    bias_degree: int = 3
    inclusion_shape: str = "auto"
    pillar_diameter_mm: float | None = None

    def __post_init__(self):
        if (self.pillar_diameter_mm is not None
            and not 0 < self.pillar_diameter_mm <= self.pillar_max_diameter_mm):
            raise ValueError(f"the pillar diameter ({self.pillar_diameter_mm:g} mm) must lie above 0 and at "
                             f"most the thickest pillar's ({self.pillar_max_diameter_mm:g} mm)")


@dataclass
class Segmentation:
    """Result of :func:`segment`.

    Attributes:
        labels: (same shape as the input) uint8 codes.
        spacing_mm: voxel size per array axis, mm.
        silicone_brighter: detected contrast.
        levels: normalised class levels after bias correction (air, silicone, hydrogel).
        thresholds: (air|tissue, dark|bright) on the normalised corrected image.
        corrected: (same shape) float32 bias-corrected, normalised, smoothed image (for QC).
        silicone: (same shape) bool, all silicone inside the insert (skin, pillars, inclusions).
        warnings: human-readable problems found.
        inclusion_shapes: per inclusion, how its surface was drawn (``shape`` "ball" or "image",
            ``centre_index``, ``ball_diameter_mm``, ``ball_misfit``; see ``SegmentParams.inclusion_shape``).
        base_surface: the base's surface under the filling, found under the pillars
            (:class:`lesscli.mri.pillar.BaseSurface`, on the input's grid); None without a pillar.
        posts: the pillars drawn, each a straight cylinder on the base's surface
            (:class:`lesscli.mri.pillar.Post`, on the input's grid).
    """

    labels: np.ndarray
    spacing_mm: np.ndarray
    silicone_brighter: bool
    levels: dict
    thresholds: tuple[float, float]
    corrected: np.ndarray
    silicone: np.ndarray
    warnings: list[str] = field(default_factory=list)
    inclusion_shapes: list[dict] = field(default_factory=list)
    base_surface: BaseSurface | None = None
    posts: list[Post] = field(default_factory=list)


def validate(image: np.ndarray, where: str) -> np.ndarray:
    """Check an MRI array and return it as float32; DataError names ``where`` and the problem."""
    arr = np.asarray(image)
    if arr.ndim == 4 and arr.shape[3] == 1:
        arr = arr[..., 0]
    if arr.ndim != 3:
        raise DataError(f"{where}: expected a 3D volume, got shape {arr.shape}")
    if min(arr.shape) < MIN_SHAPE:
        raise DataError(f"{where}: volume {arr.shape} is too small (need >= {MIN_SHAPE} voxels per axis)")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise DataError(f"{where}: expected real intensities, got dtype {arr.dtype}")
    arr = arr.astype(np.float32)
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{where}: volume contains NaN or inf ({int(np.sum(~np.isfinite(arr)))} voxels)")
    if float(arr.max()) - float(arr.min()) <= SPREAD_EPS * max(1.0, abs(float(arr.max()))):
        raise DataError(f"{where}: volume is empty (constant value {float(arr.min()):g})")
    return arr


def _sample(values: np.ndarray) -> np.ndarray:
    flat = values.ravel()
    if flat.size <= HIST_SAMPLES:
        return flat
    rng = np.random.default_rng(SAMPLE_SEED)
    return flat[rng.integers(0, flat.size, HIST_SAMPLES)]


def _levels(corrected: np.ndarray, foreground: np.ndarray) -> tuple[float, float, float]:
    """Median air level outside, and the medians of the two tissue classes inside ``foreground``."""
    from skimage.filters import threshold_otsu

    inside = _sample(corrected[foreground]) if foreground.any() else _sample(corrected)
    split = threshold_otsu(inside) if np.ptp(inside) > 0 else float(inside[0])
    low, high = inside[inside <= split], inside[inside > split]
    dark = float(np.median(low)) if low.size else float(np.median(inside))
    bright = float(np.median(high)) if high.size else dark
    outside = corrected[~foreground]
    air = float(np.median(_sample(outside))) if outside.size else float(corrected.min())
    return air, dark, bright


def _topology(tissue: np.ndarray, spacing: np.ndarray, where: str) -> tuple[np.ndarray, list[str]]:
    """The insert mask (holes filled) from the tissue mask, and warnings."""
    from scipy import ndimage
    from skimage.measure import label, regionprops

    comps = label(tissue, connectivity=1)
    voxel_mm3 = float(np.prod(spacing))
    candidates = []
    for region in regionprops(comps):
        lo, hi = np.asarray(region.bbox[:3]), np.asarray(region.bbox[3:])
        spans = int(np.sum((lo == 0) & (hi == np.asarray(tissue.shape))))   # axes crossed face to face
        if spans < 2 and region.area * voxel_mm3 >= MIN_INSERT_MM3:        # 2+: a container or a bath
            candidates.append(region)
    if not candidates:
        raise DataError(f"{where}: no insert found (no object of at least {MIN_INSERT_MM3:g} mm^3 inside the "
                        "field of view)")
    best = max(candidates, key=lambda r: r.area)
    insert = comps == best.label
    warnings = []
    lo, hi = np.asarray(best.bbox[:3]), np.asarray(best.bbox[3:])
    if np.any(lo == 0) or np.any(hi == np.asarray(tissue.shape)):
        warnings.append("insert touches the border of the scan: part of it may be cut off")
    return ndimage.binary_fill_holes(insert), warnings


def rician_mean(signal: float, sigma: float) -> float:
    """Mean magnitude of ``signal`` in complex Gaussian noise of ``sigma`` per channel (the Rice
    distribution of an MRI magnitude image): sigma sqrt(pi/2) at no signal, about sqrt(signal^2 +
    sigma^2) well above the noise."""
    from scipy.special import i0e, i1e

    if sigma <= 0:
        return abs(signal)
    nu = signal * signal / (2 * sigma * sigma)
    return sigma * math.sqrt(math.pi / 2) * ((1 + nu) * float(i0e(nu / 2)) + nu * float(i1e(nu / 2)))


def half_level(air: float, tissue: float) -> float:
    """The magnitude a voxel half air and half ``tissue`` reads on average, from the two levels read.

    In a magnitude image air reads the noise alone (its mean: sigma sqrt(pi/2)) and a tissue its signal
    lifted by the noise, so the mean of the two levels lies above that of a half-filled voxel, by up to
    a tenth of the contrast at the noise of a fast scan (the surface of a dark skin drawn up to a slice
    inside). The noise comes from the air's level, the tissue's signal from inverting the Rice mean.
    """
    sigma = max(air, 0.0) / math.sqrt(math.pi / 2)
    if tissue <= rician_mean(0.0, sigma):
        return 0.5 * (air + tissue)
    lo, hi = 0.0, tissue
    for _ in range(RICE_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if rician_mean(mid, sigma) < tissue else (lo, mid)
    return rician_mean(0.25 * (lo + hi), sigma)


def _surface(corrected: np.ndarray, insert: np.ndarray, levels: tuple[float, float, float],
             spacing: np.ndarray) -> np.ndarray:
    """The insert's outer surface at half-way between the air and the tissue just inside it, locally.

    The global air threshold sits half-way to the darker tissue; where the surface is the brighter one
    (a silicone skin brighter than the filling), that is well below the partial-volume midpoint and the
    insert would grow. Within SURFACE_BAND_VOXELS of the surface each voxel is compared with what a
    voxel half air and half the tissue of the layer beneath reads (:func:`half_level`; the layer's level
    averaged over SURFACE_SIGMA_MM and snapped to the nearer of the two tissue levels, so that partial
    volume does not blur the choice).

    Args:
        levels: (air, dark tissue, bright tissue) levels of ``corrected``.
    """
    from scipy import ndimage

    from lesscli.mri.morphology import crop_box

    air, dark, bright = levels
    box = crop_box(insert, int(np.ceil(2 * SURFACE_BAND_VOXELS)) + 1)
    ins, img = insert[box], corrected[box]
    voxel = float(spacing.max())
    inside = ndimage.distance_transform_edt(ins, sampling=spacing)
    outside = ndimage.distance_transform_edt(~ins, sampling=spacing)
    band_mm = SURFACE_BAND_VOXELS * voxel
    # the layer is at least a voxel thick: slices must not fall past it
    depth = SURFACE_LAYER_VOXELS * voxel
    layer = ins & (inside > depth) & (inside <= depth + max(SURFACE_LAYER_MM, voxel))
    sigma = SURFACE_SIGMA_MM / spacing
    weight = ndimage.gaussian_filter(layer.astype(np.float32), sigma)
    level = ndimage.gaussian_filter(np.where(layer, img, 0.0).astype(np.float32), sigma) / np.maximum(weight,
                                                                                                     1e-6)
    band = ((ins & (inside <= band_mm)) | (~ins & (outside <= band_mm))) & (weight > SURFACE_MIN_WEIGHT)
    threshold = np.where(np.abs(level - dark) <= np.abs(level - bright), half_level(air, dark),
                         half_level(air, bright))
    refined = np.where(band, img > threshold, ins)
    out = insert.copy()
    out[box] = ndimage.binary_fill_holes(refined)
    return out


def _check_contrast(corrected: np.ndarray, insert: np.ndarray, where: str) -> None:
    inside, outside = _sample(corrected[insert]), _sample(corrected[~insert])
    spread = max(robust_sigma(outside), SPREAD_EPS)
    contrast = (float(np.median(inside)) - float(np.median(outside))) / spread
    if contrast < MIN_CONTRAST:
        raise DataError(f"{where}: no insert found (object/background contrast {contrast:.1f} is below "
                        f"{MIN_CONTRAST:g}; is this a scan of an insert?)")


def segment(image: np.ndarray, spacing_mm, params: SegmentParams = SegmentParams(),
            where: str = "scan") -> Segmentation:
    """Label an MRI volume of an insert.

    1. validate (3D, finite, not constant) and normalise intensities to the 99.5th percentile;
    2. Gaussian smoothing (sigma in mm) against noise;
    3. bias-field correction: a smooth multiplicative field ``exp(poly(x, y, z))`` fitted to the log
       intensities of the two tissue classes inside the object (:mod:`lesscli.mri.bias`);
    4. three-class thresholding: class levels (air, dark tissue, bright tissue) from multi-Otsu, then
       thresholds half-way between adjacent levels;
    5. topology: a component that crosses the scan from face to face along two or more axes is
       background, and so is everything below the air threshold; the insert is the largest remaining
       object of at least MIN_INSERT_MM3 (else: no insert), holes filled;
    6. silicone: the minority tissue of the insert;
    7. silicone morphology (:func:`lesscli.mri.morphology.split_silicone`).

    Args:
        image: 3D array of intensities, any axis order; ``spacing_mm`` follows the same axes.
        spacing_mm: (3,) voxel size per array axis, mm.
        params: morphology sizes and smoothing.
        where: name used in error messages (the file).

    Returns:
        Segmentation with uint8 labels of the same shape as ``image``.

    Raises:
        DataError: not a 3D finite non-constant volume, or no insert found.
    """
    from scipy import ndimage

    from lesscli.mri.bias import correct_bias
    from lesscli.mri.morphology import split_silicone

    arr = validate(image, where)
    spacing = np.asarray(spacing_mm, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(spacing) & (spacing > 0)):
        raise DataError(f"{where}: voxel spacing must be positive, got {spacing.tolist()} mm")
    arr = arr - min(float(arr.min()), 0.0)             # magnitudes are >= 0; shift signed data
    scale = float(np.percentile(_sample(arr), NORM_PERCENTILE)) or float(arr.max())
    smooth_mm = params.smooth_mm if params.smooth_mm is not None else SMOOTH_VOXELS * float(spacing.min())
    smoothed = (ndimage.gaussian_filter(arr / scale, sigma=smooth_mm / spacing) if smooth_mm > 0
                else arr / scale)
    corrected, foreground = correct_bias(smoothed, spacing, params.bias_degree)
    air, dark, bright = _levels(corrected, foreground)
    t_air, t_tissue = 0.5 * (air + dark), 0.5 * (dark + bright)
    insert, warnings = _topology(corrected > t_air, spacing, where)
    _check_contrast(corrected, insert, where)
    insert = _surface(corrected, insert, (air, dark, bright), spacing)
    bright_mask = insert & (corrected > t_tissue)
    n_bright, n_insert = int(bright_mask.sum()), int(insert.sum())
    silicone_brighter = n_bright < n_insert - n_bright
    silicone = bright_mask if silicone_brighter else insert & ~bright_mask
    sil_level, gel_level = (bright, dark) if silicone_brighter else (dark, bright)
    fraction = (corrected - np.float32(gel_level)) / np.float32(sil_level - gel_level)
    pillar, inclusion, more, shapes, base, posts = split_silicone(silicone, insert, spacing,
                                                                  params.pillar_max_diameter_mm,
                                                                  params.skin_max_thickness_mm, fraction,
                                                                  params.inclusion_shape,
                                                                  params.pillar_diameter_mm,
                                                                  smooth_mm / spacing)
    labels = np.full(arr.shape, BACKGROUND, dtype=np.uint8)
    labels[insert] = INSERT
    labels[pillar] = PILLAR
    labels[inclusion] = INCLUSION
    levels = {"air": air, "silicone": sil_level, "hydrogel": gel_level}
    return Segmentation(labels, spacing, silicone_brighter, levels, (t_air, t_tissue),
                        corrected.astype(np.float32), silicone, warnings + more, shapes, base, posts)
