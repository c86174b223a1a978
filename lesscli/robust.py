"""Robust scale: the standard deviation of normal scatter read from the median absolute deviation, one
definition for every module that reads a noise level or tells outliers apart."""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826           # median absolute deviation -> standard deviation of a normal distribution


def robust_sigma(values: np.ndarray, centre: float | None = None) -> float:
    """MAD_TO_SIGMA times the median absolute deviation of ``values`` (non-empty) about ``centre`` (their
    median where None): the standard deviation of normal scatter, which a minority of outliers does not
    move."""
    values = np.asarray(values)
    if centre is None:
        centre = np.median(values)
    return MAD_TO_SIGMA * float(np.median(np.abs(values - centre)))
