"""Operator monitor frames and guidance overlays (matplotlib, Agg backend chosen inside each function).

A monitor frame shows, side by side and on the same phantom-frame axes (x, y mm): the label image, the
per-pixel uncertainty (Shannon entropy, nats; 0 .. ln C) and the touched pad positions, like the
operator monitor of the hand-held system. 3D images are shown as top views: the label panel marks a
pixel with the most salient class found anywhere in its column (inclusion > pillar > insert), and the
uncertainty panel shows the column's mean entropy.
"""

from __future__ import annotations

import numpy as np

from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, PILLAR
from lesscli.plots.palette import CLASS_RGBA

# display rank of each class code in a top view (higher wins within a column)
_SALIENCE = np.zeros(4, np.int64)
_SALIENCE[[BACKGROUND, INSERT, PILLAR, INCLUSION]] = [0, 1, 2, 3]


def top_view(labels: np.ndarray, entropy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D, H, W) labels and entropy -> (H, W) most salient label per column and mean column entropy."""
    rank = _SALIENCE[labels]
    top = np.take_along_axis(labels, rank.argmax(axis=0)[None], 0)[0]
    return top, entropy.mean(axis=0)


def _extent(origin_mm, spacing_mm, shape) -> list[float]:
    """imshow extent (x0, x1, y0, y1) in mm of an (H, W) image whose rows follow y."""
    h, w = shape
    return [origin_mm[2] - spacing_mm[2] / 2, origin_mm[2] + (w - 0.5) * spacing_mm[2],
            origin_mm[1] - spacing_mm[1] / 2, origin_mm[1] + (h - 0.5) * spacing_mm[1]]


def monitor_frame(path: str, labels: np.ndarray, entropy: np.ndarray, touches_xy_mm: np.ndarray,
                  origin_mm, spacing_mm, n_classes: int, title: str = "",
                  marks_xy_mm: np.ndarray | None = None) -> None:
    """Write one PNG: image | uncertainty | touched positions.

    Args:
        path: output PNG path (written as is; callers wanting atomicity pass a temp path).
        labels: (D, H, W) uint8 class codes.
        entropy: (D, H, W) float entropy, nats.
        touches_xy_mm: (n, 2) pad x, y of every sample so far.
        origin_mm, spacing_mm: z, y, x geometry of voxel [0, 0, 0] and the voxel size.
        n_classes: C (the entropy scale ends at ln C).
        title: figure title.
        marks_xy_mm: optional (k, 2) suggested touch locations, drawn as numbered crosses.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top, ent = top_view(labels, entropy)
    ext = _extent(origin_mm, spacing_mm, top.shape)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.8), constrained_layout=True)
    axes[0].imshow(CLASS_RGBA[top], origin="lower", extent=ext, interpolation="nearest")
    axes[0].set_title("image")
    im = axes[1].imshow(ent, origin="lower", extent=ext, cmap="magma", vmin=0.0,
                        vmax=float(np.log(n_classes)))
    axes[1].set_title("uncertainty (nats)")
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    axes[2].imshow(CLASS_RGBA[top], origin="lower", extent=ext, interpolation="nearest", alpha=0.35)
    if len(touches_xy_mm):
        axes[2].scatter(touches_xy_mm[:, 0], touches_xy_mm[:, 1], s=4, c="k")
    axes[2].set_title(f"touches ({len(touches_xy_mm)})")
    if marks_xy_mm is not None:
        for ax in axes[1:]:
            ax.scatter(marks_xy_mm[:, 0], marks_xy_mm[:, 1], marker="x", s=80, c="c", linewidths=2)
            for i, (x, y) in enumerate(marks_xy_mm):
                ax.annotate(str(i + 1), (x, y), xytext=(4, 4), textcoords="offset points", color="c")
    for ax in axes:
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
        ax.set_xlabel("x (mm)")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y (mm)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=80, format="png")
    plt.close(fig)
