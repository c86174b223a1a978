"""Colour tables for label volumes, in the formats 3D Slicer and ITK-SNAP load, so that a label NIfTI opens
with the toolkit's class names and colours (the figures' palette) instead of a generic lookup table.

- 3D Slicer: a colour table file (``.ctbl``; *Add Data*, then pick it as the volume's lookup table):
  lines ``index name R G B A``, 0..255.
- ITK-SNAP: a label description file (``.txt``; *Segmentation > Import Label Descriptions*): lines
  ``IDX R G B A VIS MSH "LABEL"``, colours 0..255, A (opacity) 0..1.

Background (code 0) is written transparent in both, so only the classes show over an image.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

SLICER_NAME = "labels.ctbl"
ITKSNAP_NAME = "labels_itksnap.txt"


def _rgb255(rgba) -> tuple[int, int, int]:
    return tuple(round(float(v) * 255) for v in np.asarray(rgba, np.float64)[:3])


def slicer_table(names: Sequence[str], rgba) -> str:
    """A 3D Slicer colour table for codes 0..n-1 named ``names`` with colours ``rgba`` ((n, 4) in 0..1)."""
    lines = ["# Color table file (3D Slicer): less label classes", f"# {len(names)} values"]
    for code, (name, colour) in enumerate(zip(names, rgba)):
        r, g, b = _rgb255(colour)
        lines.append(f"{code} {name} {r} {g} {b} {0 if code == 0 else 255}")
    return "\n".join(lines) + "\n"


def itksnap_table(names: Sequence[str], rgba) -> str:
    """An ITK-SNAP label description file for codes 0..n-1 (see the module docstring)."""
    lines = ["################################################", "# ITK-SnAP Label Description File",
             "# File format:", "# IDX   -R-  -G-  -B-  -A--  VIS MSH  LABEL", "# Fields:",
             "#    IDX:   Zero-based index", "#    -R-:   Red color component (0..255)",
             "#    -G-:   Green color component (0..255)", "#    -B-:   Blue color component (0..255)",
             "#    -A-:   Label transparency (0.00 .. 1.00)", "#    VIS:   Label visibility (0 or 1)",
             "#    MSH:   Label mesh visibility (0 or 1)", "#  LABEL:   Label description",
             "################################################"]
    for code, (name, colour) in enumerate(zip(names, rgba)):
        r, g, b = _rgb255(colour)
        shown = 0 if code == 0 else 1
        lines.append(f"{code:5d} {r:5d} {g:4d} {b:4d} {shown:8.2f} {shown:2d} {shown:2d}    \"{name}\"")
    return "\n".join(lines) + "\n"


def write_colour_tables(folder: str, names: Sequence[str], rgba) -> list[str]:
    """Write both tables into ``folder``; returns their paths."""
    import os

    paths = []
    for name, text in ((SLICER_NAME, slicer_table(names, rgba)), (ITKSNAP_NAME, itksnap_table(names, rgba))):
        path = os.path.join(folder, name)
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
        paths.append(path)
    return paths
