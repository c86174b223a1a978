"""Figures of sweeps: a metric against pose noise (one line per angle level), accuracy against time
(the trade-off's settings, the contact tiers of ``bench sim``) and F1 against touches (``bench guide``).

Each function builds its own Agg canvas (no global backend state) and writes the figure atomically, as a
PNG, or a PDF or SVG where the path's extension says so (:func:`save_figure`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from lesscli.io.atomic import atomic_path
from lesscli.plots.render import agg_figure

FIGSIZE_IN = (6.4, 4.4)
LADDER_DPI = 120
LADDER_STYLE = {"winkler": ("o", "tab:orange"), "green": ("s", "tab:blue"), "fem": ("^", "tab:green")}


FIGURE_FORMATS = ("png", "pdf", "svg")


def figure_format(path: str) -> str:
    """The format a figure path asks for by its extension (png, pdf or svg); png for ``-`` and for any
    other name."""
    ext = path.rsplit(".", 1)[-1].lower() if "." in path.rsplit("/", 1)[-1] else ""
    return ext if ext in FIGURE_FORMATS else "png"


def save_figure(fig, path: str, dpi: float | None = None) -> None:
    """Write ``fig`` to ``path`` atomically in the format its extension names (:func:`figure_format`: a
    vector PDF or SVG for ``.pdf`` / ``.svg``, else a PNG at the figure's own dpi unless ``dpi`` is given)."""
    import matplotlib

    fmt = figure_format(path)
    metadata = {"pdf": {"CreationDate": None}, "svg": {"Date": None}}.get(fmt)     # no clock time inside
    # nor random ids
    with atomic_path(path, "." + fmt) as tmp, matplotlib.rc_context({"svg.hashsalt": "less"}):
        fig.savefig(tmp, format=fmt, dpi=dpi, **({"metadata": metadata} if metadata else {}))



def _num(value) -> float:
    return float("nan") if value is None else float(value)


NOISE_MARKERS = "osD^v<>pP*Xh"
NOISE_STYLES = ("-", "--", "-.", ":")
DODGE_SHARE = 0.012             # lines of the angle levels shifted apart along x by this share of the axis


def noise_figure(rows: Sequence[Mapping], path: str, metric: str = "f1", title: str = "") -> None:
    """Metric vs position-noise sigma, one line per angle sigma, error bars = std over repeats.

    F1 is drawn in percent on the full 0-100 % axis, so a change of a few points looks like one and not
    like a collapse; each angle level has its own marker and line style and is shifted a little along x,
    so lines that coincide (robust cells) stay visible side by side.

    Args:
        rows: sweep rows with ``pos_mm``, ``ang_rad``, ``<metric>`` and ``<metric>_std``.
        path: output figure (PNG, PDF or SVG by its extension).
        metric: the plotted key (F1 values in [0, 1] are drawn in percent).
        title: figure title.
    """
    fig = agg_figure(FIGSIZE_IN)
    ax = fig.add_subplot(1, 1, 1)
    is_f1 = metric.startswith("f1")
    scale = 100.0 if is_f1 else 1.0
    angles = sorted({float(r["ang_rad"]) for r in rows})
    xs = [float(r["pos_mm"]) for r in rows]
    span = (max(xs) - min(xs)) if xs else 0.0
    dodge = DODGE_SHARE * (span or 1.0)
    top = 0.0
    for i, ang in enumerate(angles):
        line = sorted((r for r in rows if float(r["ang_rad"]) == ang), key=lambda r: float(r["pos_mm"]))
        x = np.array([float(r["pos_mm"]) for r in line]) + (i - (len(angles) - 1) / 2) * dodge
        y = np.array([_num(r.get(metric)) for r in line]) * scale
        err = np.nan_to_num(np.array([_num(r.get(f"{metric}_std")) for r in line]), nan=0.0) * scale
        ax.errorbar(x, y, yerr=err, marker=NOISE_MARKERS[i % len(NOISE_MARKERS)], capsize=3, alpha=0.85,
                    ls=NOISE_STYLES[i % len(NOISE_STYLES)], markerfacecolor="none", label=f"{ang:g} rad")
        finite = y[np.isfinite(y)]
        top = max(top, float((finite + err[np.isfinite(y)]).max()) if finite.size else 0.0)
    if is_f1:
        ax.set_ylim(0.0, 100.0)
    else:
        ax.set_ylim(0.0, top * 1.1 if top > 0 else 1.0)           # errors from zero, not zoomed in
    ax.set_xlabel("position noise sigma (x, y, z), mm")
    ax.set_ylabel(f"{metric} (%)" if scale != 1.0 else metric)
    ax.legend(title="angle noise sigma", fontsize="small")
    ax.grid(alpha=0.3)
    ax.set_title(title or "Pose-noise robustness (phantom frame, i.i.d. Gaussian)")
    save_figure(fig, path)


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated by another (lower or equal time and higher or equal score,
    one strictly), sorted by time. NaN points are never on the front."""
    idx = [i for i, (t, s) in enumerate(points) if np.isfinite(t) and np.isfinite(s)]
    front = []
    for i in idx:
        ti, si = points[i]
        dominated = any((points[j][0] <= ti and points[j][1] >= si)
                        and (points[j][0] < ti or points[j][1] > si)
                        for j in idx if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def _pareto_panel(ax, rows: Sequence[Mapping], time_key: str, score: str,
                  refs: Sequence[Mapping] = ()) -> None:
    """One panel: ``score`` (percent, error bars from ``<score>_std``) against ``time_key`` (log) per
    setting, one marker per knob, the Pareto front as a line and each reference row's score as a
    horizontal line."""
    knobs = list(dict.fromkeys(str(r["knob"]) for r in rows))
    pts = [(_num(r.get(time_key)), _num(r.get(score)) * 100.0) for r in rows]
    for k, knob in enumerate(knobs):
        sel = [i for i, r in enumerate(rows) if str(r["knob"]) == knob]
        err = [_num(rows[i].get(f"{score}_std")) * 100.0 for i in sel]
        ax.errorbar([pts[i][0] for i in sel], [pts[i][1] for i in sel],
                    yerr=np.nan_to_num(np.asarray(err, float), nan=0.0),
                    fmt=NOISE_MARKERS[k % len(NOISE_MARKERS)], capsize=2, label=knob, zorder=3)
        for i in sel:
            ax.annotate(str(rows[i]["value"]), pts[i], fontsize=7, xytext=(3, 3), textcoords="offset points")
    front = pareto_front(pts)
    if front:
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k--", lw=1, label="Pareto front")
    for j, ref in enumerate(refs):
        ax.axhline(_num(ref.get(score)) * 100.0, color=f"C{(j + 7) % 10}", ls=":", lw=1.2,
                   label=f"{ref['value']} (reference)")
    ax.set_xscale("log")
    ax.set_xlabel(f"{time_key} (log)")
    ax.set_ylabel(f"{score} (%)")
    ax.grid(alpha=0.3)


def pareto_figure(rows: Sequence[Mapping], path: str, time_key: str | Sequence[str] = "train_s",
                  scores: Sequence[str] = ("f1_single", "f1_multiple"), title: str = "") -> None:
    """Score vs time per setting (one marker per knob), the Pareto front of each panel as a line.

    Args:
        rows: one row per setting with ``knob``, ``value``, the time keys and the score keys; rows whose
            ``knob`` is ``"reference"`` are drawn as horizontal lines (e.g. the classical imager).
        path: output figure.
        time_key: the x axis, or several: one column of panels each.
        scores: the y keys, one row of panels each (F1 in [0, 1], drawn in percent).
        title: figure title.
    """
    time_keys = [time_key] if isinstance(time_key, str) else list(time_key)
    refs = [r for r in rows if r.get("knob") == "reference"]
    rows = [r for r in rows if r.get("knob") != "reference"]
    pairs = [(t, sc) for sc in scores for t in time_keys]          # one time axis: the scores side by side
    n_rows, n_cols = (len(scores), len(time_keys)) if len(time_keys) > 1 else (1, len(scores))
    fig = agg_figure((5.2 * n_cols, 4.4 * n_rows))
    axes = fig.subplots(n_rows, n_cols, squeeze=False).ravel()
    panels = [(ax, t, sc) for ax, (t, sc) in zip(axes, pairs)]
    for ax, t, sc in panels:
        _pareto_panel(ax, rows, t, sc, refs)
    panels[0][0].legend(fontsize="x-small")
    fig.suptitle(title or "Accuracy against time")
    save_figure(fig, path)


def line_figure(rows: Sequence[Mapping], path: str, x_key: str, y_keys: Sequence[str], xlabel: str,
                title: str = "") -> None:
    """Scores vs one setting (e.g. F1 on single and multiple vs receptive field), F1 in percent.

    Rows may carry ``<y>_std`` for error bars.
    """
    fig = agg_figure(FIGSIZE_IN)
    ax = fig.add_subplot(1, 1, 1)
    line = sorted(rows, key=lambda r: float(r[x_key]))
    x = np.array([float(r[x_key]) for r in line])
    for key in y_keys:
        y = np.array([_num(r.get(key)) for r in line]) * 100.0
        err = np.nan_to_num(np.array([_num(r.get(f"{key}_std")) for r in line]), nan=0.0) * 100.0
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=key)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("F1 (%)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title)
    save_figure(fig, path)


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
    save_figure(fig, path)


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
    save_figure(fig, path, dpi=LADDER_DPI)
