"""Figures of the benchmarks (``less bench NAME --plot``), each on its own Agg canvas, written atomically.

- :func:`touches_figure`: inclusion F1 against the number of touches, one line per strategy (``bench guide``);
- :func:`ladder_figure`: relative error against time per step of the contact tiers (``bench sim``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from lesscli.plots.render import agg_figure
from lesscli.plots.sweeps import save_png

LADDER_DPI = 120
LADDER_STYLE = {"winkler": ("o", "tab:orange"), "green": ("s", "tab:blue"), "fem": ("^", "tab:green")}


def touches_figure(path: str, means: Mapping[str, Sequence[tuple[int, float]]], title: str) -> None:
    """F1 vs touches (markers at the evaluation points).

    Args:
        path: output PNG.
        means: strategy -> [(touches, F1)], the F1 averaged over phantoms and seeds.
        title: figure title.
    """
    fig = agg_figure((5.5, 4))
    ax = fig.add_subplot(1, 1, 1)
    for s, curve in means.items():
        ax.plot([n for n, _ in curve], [f for _, f in curve], marker="o", ms=3, label=s)
    ax.set_xlabel("touches")
    ax.set_ylabel("inclusion F1 (mean over phantoms and seeds)")
    ax.set_title(title)
    ax.legend()
    save_png(fig, path)


def ladder_figure(rows: Sequence[Mapping], path: str) -> None:
    """Error vs time per step (log-log), one marker per tier, labelled by check and mesh.

    Rows without an error or a time (the reference itself has error 0) are left out.
    """
    fig = agg_figure((7, 5))
    ax = fig.add_subplot(1, 1, 1)
    for row in rows:
        if not row.get("error") or not row.get("ms_per_step"):
            continue
        err = float(row["error"])
        marker, colour = LADDER_STYLE.get(row["tier"], ("x", "k"))
        ax.scatter(row["ms_per_step"], err, marker=marker, color=colour, label=row["tier"])
        mesh = f" {row['mesh_mm']:g}mm" if row.get("mesh_mm") else ""
        ax.annotate(f"{row['check']}{mesh}", (row["ms_per_step"], err), fontsize=7)
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles))
    ax.legend(uniq.values(), uniq.keys())
    ax.set(xscale="log", yscale="log", xlabel="time per step (ms)", ylabel="relative error",
           title="contact tiers: accuracy vs time")
    save_png(fig, path, dpi=LADDER_DPI)
