"""Class colours shared by figures and meshes (RGBA in 0..1, indexed by label code)."""

from __future__ import annotations

import numpy as np

from lesscli.io.labels import CLASS_NAMES

CLASS_RGBA = np.array([
    (1.00, 1.00, 1.00, 1.0),   # background: white
    (0.80, 0.80, 0.78, 1.0),   # insert: light grey
    (0.20, 0.45, 0.85, 1.0),   # pillar: blue
    (0.85, 0.15, 0.15, 1.0),   # inclusion: red
])


def class_colour(code: int) -> tuple[float, float, float, float]:
    """RGBA of a label code."""
    return tuple(float(v) for v in CLASS_RGBA[int(code)])


def class_name(code: int) -> str:
    return CLASS_NAMES[int(code)]
