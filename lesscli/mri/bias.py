"""Bias-field correction: a smooth multiplicative field ``exp(p(x, y, z))`` with ``p`` a low-degree
polynomial.

Inside the object (eroded away from partial-volume boundaries) the log intensity is a tissue level
plus ``p``. Alternating between a two-class split of the corrected log intensities and a least-squares
fit of ``p`` to the residuals (outliers trimmed) estimates the field, which is then divided out.

The trimming leaves out the voxels that mix the two tissues only where the noise is low: its window is
three robust standard deviations of the residuals, which the noise holds wide enough to keep them, and
they bend the polynomial towards the other tissue's level where they gather (the skin, the base, the
inclusions' surfaces). So the field is fitted again, from the first fit, to the voxels at least
TISSUE_MARGIN_VOXELS from any boundary between the tissues that the first fit's split draws.
"""

from __future__ import annotations

import itertools

import numpy as np

ERODE_MM = 1.0                  # stay this far inside the object when fitting
ITERATIONS = 4
TRIM_MAD = 3.0                  # residuals beyond this many MADs are left out of the fit
FIT_SAMPLES = 40_000
MIN_FIT_VOXELS = 200
LOG_EPS = 1e-6
RIDGE = 1e-6                    # keeps the normal equations well posed
SAMPLE_SEED = 0
# the refit leaves out voxels this close to the other tissue (Chebyshev, voxels)
TISSUE_MARGIN_VOXELS = 2


def _powers(degree: int) -> list[tuple[int, int, int]]:
    return [p for p in itertools.product(range(degree + 1), repeat=3) if 0 < sum(p) <= degree]


def _unit_axes(shape: tuple[int, ...]) -> list[np.ndarray]:
    """Per-axis coordinates scaled to [-1, 1] (conditioning of the polynomial fit)."""
    return [np.linspace(-1.0, 1.0, n) for n in shape]


def _design(idx: np.ndarray, axes: list[np.ndarray], powers) -> np.ndarray:
    coords = [axes[a][idx[:, a]] for a in range(3)]
    return np.stack([coords[0] ** p[0] * coords[1] ** p[1] * coords[2] ** p[2] for p in powers], axis=1)


def _evaluate(coef: np.ndarray, axes: list[np.ndarray], powers, degree: int) -> np.ndarray:
    """Separable evaluation of sum_c coef_c x^a y^b z^c on the grid of ``axes``, float32."""
    tensor = np.zeros((degree + 1,) * 3)
    for c, p in zip(coef, powers):
        tensor[p] = c
    basis = [np.stack([ax ** k for k in range(degree + 1)]) for ax in axes]     # (deg+1, n)
    return np.einsum("abc,ai,bj,ck->ijk", tensor, *basis, optimize=True).astype(np.float32)


def _split(values: np.ndarray) -> np.ndarray:
    from skimage.filters import threshold_otsu

    return values > threshold_otsu(values)


def _matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a @ x without BLAS threads (thin matrices: threading costs more than it saves on busy machines)."""
    return np.einsum("ni,i->n", a, x)


def fit_log_field(log_values: np.ndarray, design: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """Polynomial coefficients of the log bias from (n,) log intensities and the (n, k) design matrix,
    the rounds starting from the coefficients ``start`` (None: no field)."""
    coef = np.zeros(design.shape[1]) if start is None else np.asarray(start, dtype=np.float64)
    for _ in range(ITERATIONS):
        corrected = log_values - _matvec(design, coef)
        cls = _split(corrected)
        level = np.where(cls, np.median(corrected[cls]), np.median(corrected[~cls]))
        resid = log_values - level
        dev = resid - _matvec(design, coef)
        mad = float(np.median(np.abs(dev - np.median(dev)))) + LOG_EPS
        keep = np.abs(dev - np.median(dev)) <= TRIM_MAD * mad / 0.6745
        if keep.sum() < MIN_FIT_VOXELS:
            break
        a = np.column_stack([np.ones(int(keep.sum())), design[keep]])
        gram = np.einsum("ni,nj->ij", a, a) + RIDGE * np.eye(a.shape[1])   # normal equations, k x k
        sol = np.linalg.solve(gram, np.einsum("ni,n->i", a, resid[keep]))
        coef = sol[1:]
    return coef


def _log(values: np.ndarray) -> np.ndarray:
    return np.log(np.maximum(values, LOG_EPS, dtype=np.float32))


def _sample_fit(smoothed: np.ndarray, mask: np.ndarray, axes, powers, rng, start=None) -> np.ndarray:
    """:func:`fit_log_field` on up to FIT_SAMPLES voxels of ``mask`` drawn at random."""
    idx = np.argwhere(mask)
    if len(idx) > FIT_SAMPLES:
        idx = idx[rng.choice(len(idx), FIT_SAMPLES, replace=False)]
    return fit_log_field(_log(smoothed[tuple(idx.T)]).astype(np.float64), _design(idx, axes, powers), start)


def _away_from_boundaries(smoothed: np.ndarray, fitted: np.ndarray, coef: np.ndarray, axes, powers,
                          degree: int, voxels: int, rng) -> np.ndarray:
    """The voxels of ``fitted`` at least ``voxels`` (Chebyshev) from any voxel of the other class, the
    classes split as the fit's rounds split them (Otsu on the log intensities, corrected by the field of
    ``coef``, of its voxels; the air falls with the darker tissue)."""
    from scipy import ndimage
    from skimage.filters import threshold_otsu

    from lesscli.mri.morphology import crop_box

    box = crop_box(fitted, voxels)              # the filters see every voxel within reach of the fitted ones
    log_box = _log(smoothed[box]) - _evaluate(coef, [ax[b] for ax, b in zip(axes, box)], powers, degree)
    fitted_box = fitted[box]
    values = log_box[fitted_box]
    if len(values) > 2 * FIT_SAMPLES:
        values = values[rng.choice(len(values), 2 * FIT_SAMPLES, replace=False)]
    upper = (log_box > threshold_otsu(values)).view(np.uint8)
    size = 2 * voxels + 1
    clear = np.zeros_like(fitted)
    clear[box] = fitted_box & (ndimage.maximum_filter(upper, size=size)
                               == ndimage.minimum_filter(upper, size=size))
    return clear


def _eroded(mask: np.ndarray, spacing_mm: np.ndarray, depth_mm: float) -> np.ndarray:
    """``mask``'s voxels more than ``depth_mm`` from every voxel outside it (the array's border is not
    outside), the distance transform taken over the mask's bounding box and a voxel around it: every voxel
    outside the mask beyond that box has one in the box's outer layer at least as near, so the result is the
    whole
    array's, at the cost of the box (a third of a scan whose field of view leaves air around the insert)."""
    from scipy import ndimage

    from lesscli.mri.morphology import crop_box

    out = np.zeros(mask.shape, dtype=bool)
    if mask.any():
        box = crop_box(mask, 1)
        out[box] = ndimage.distance_transform_edt(mask[box], sampling=spacing_mm) > depth_mm
    return out


def correct_bias(smoothed: np.ndarray, spacing_mm: np.ndarray, degree: int = 3,
                 margin_voxels: int = TISSUE_MARGIN_VOXELS) -> tuple[np.ndarray, np.ndarray]:
    """Divide a smooth multiplicative field out of ``smoothed``.

    Args:
        smoothed: (3D) denoised, normalised intensities.
        spacing_mm: (3,) voxel size per axis.
        degree: polynomial degree of the log field (0 disables the correction).
        margin_voxels: the refit's distance from the tissues' boundaries (0: the first fit stands).

    Returns:
        (corrected image float32, foreground mask used for the fit (eroded object), bool).
    """
    from skimage.filters import threshold_multiotsu

    rng = np.random.default_rng(SAMPLE_SEED)
    flat = smoothed.ravel()
    sample = flat[rng.integers(0, flat.size, min(flat.size, FIT_SAMPLES * 2))]
    try:
        t_low = float(threshold_multiotsu(sample, classes=3)[0])
    except ValueError:                      # too few distinct values for three classes
        t_low = float(np.median(sample))
    obj = smoothed > t_low
    inner = _eroded(obj, spacing_mm, ERODE_MM)
    if degree <= 0 or inner.sum() < MIN_FIT_VOXELS:
        return smoothed.astype(np.float32), inner if inner.any() else obj
    axes = _unit_axes(smoothed.shape)
    powers = _powers(degree)
    coef = _sample_fit(smoothed, inner, axes, powers, rng)
    if margin_voxels > 0:
        clear = _away_from_boundaries(smoothed, inner, coef, axes, powers, degree, margin_voxels, rng)
        if clear.sum() >= MIN_FIT_VOXELS:
            coef = _sample_fit(smoothed, clear, axes, powers, rng, start=coef)
    field = np.exp(_evaluate(coef, axes, powers, degree))
    return (smoothed / field).astype(np.float32), inner
