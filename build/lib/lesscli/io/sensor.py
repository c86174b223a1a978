"""Sensor layouts stored in scan-set ``meta['sensor']``.

The default is the 30-taxel Xela uSCu pad: 6 x 5 taxels at 4.7 mm pitch, 3 axes each (x, y shear;
z normal). Taxel positions are in the pad frame (mm), pad centre at the origin, row-major from
-x/-y.
"""

from __future__ import annotations

import numpy as np

XELA_PITCH_MM = 4.7
XELA_COLS, XELA_ROWS = 6, 5


def grid_layout(cols: int, rows: int, pitch_mm: float, name: str) -> dict:
    """A rectangular taxel grid as a meta-ready dict."""
    xs = (np.arange(cols) - (cols - 1) / 2) * pitch_mm
    ys = (np.arange(rows) - (rows - 1) / 2) * pitch_mm
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    return {"name": name, "taxels": cols * rows, "axes": ["x", "y", "z"], "pitch_mm": pitch_mm,
            "pad_size_mm": [cols * pitch_mm, rows * pitch_mm], "taxel_xy_mm": xy.round(6).tolist()}


def xela_uscu() -> dict:
    """The default 30-taxel Xela uSCu layout."""
    return grid_layout(XELA_COLS, XELA_ROWS, XELA_PITCH_MM, "xela-uSCu")
