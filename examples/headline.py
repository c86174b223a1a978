"""The headline table from `less metrics --summary-only --format jsonl` (accuracy.mk).

    python examples/headline.py results/accuracy/accuracy.jsonl > results/accuracy/headline.md

The paper's metric first (2D: each volume's slice of largest true inclusion area), 3D beside it; mean ±
std over seeds for learned imagers; the generalisation ratios (multiple / single, large / single) of every
imager; and the paper's own numbers (real data, REFERENCE.md) for orientation.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from pathlib import Path

IMAGERS = ["less", "global", "less-taxel", "global-taxel", "forcemap", "average"]
NAMES = {"forcemap": "classical", "average": "average"}
SET_NAMES = {"test": "single (held-out scans)", "handheld": "hand-held-like",
             "train": "train (its own scans)", "val": "validation"}
SET_ORDER = ["val", "single", "test", "multiple", "large", "handheld", "train"]
SINGLE = ("single", "test")
COLUMNS = [("f1_micro_2d", "2D F1", 3), ("com_error_mm_2d", "2D centroid mm", 2),
           ("diameter_error_mm_2d", "2D diameter mm", 2), ("f1_micro_3d", "3D F1", 3),
           ("com_error_mm_3d", "3D centroid mm", 2), ("diameter_error_mm_3d", "3D diameter mm", 2)]
# the paper's Table (real data): set -> model -> (diameter error mm, centroid error mm, F1 %)
PAPER = {"single": {"global": (1.8, 1.7, 85.2), "less": (1.5, 1.7, 83.5)},
         "multiple": {"global": (None, 7.4, 44.6), "less": (None, 4.0, 71.1)},
         "large": {"global": (9.0, 26.8, 1.1), "less": (2.7, 2.3, 71.3)}}


FILE = re.compile(r"pred_(?:img_)?(?P<name>.+?)(?:_s\d+)?_on_(?P<set>[^/]+)\.npz$")


def cell(row: dict, key: str, digits: int) -> str:
    value = row.get(key)
    if value is None:
        return "-"
    std = row.get(f"{key}_std")
    spread = f" ± {std:.{digits}f}" if std is not None and row.get("n", 1) > 1 else ""
    return f"{value:.{digits}f}{spread}"


def read_groups(path: str) -> dict:
    """(set, imager) -> mean and std (ddof 1) over seeds of each column, from the per-file summaries; an
    imager is named by its prediction files (``pred_img_<name>_s<seed>_on_<set>.npz``), the average
    baseline by its model."""
    rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    runs: dict = {}
    for r in rows:
        match = FILE.search(r.get("file") or "")
        if r.get("row") != "file" or match is None:
            continue
        name = "average" if r["model"] == "average" else match["name"]
        runs.setdefault((match["set"], name), []).append(r)
    groups = {}
    for key, files in runs.items():
        group = {"n": len(files)}
        for column, _, _ in COLUMNS[:6]:
            values = [f[column] for f in files if f.get(column) is not None]
            if values:
                group[column] = statistics.fmean(values)
                group[f"{column}_std"] = statistics.stdev(values) if len(values) > 1 else None
        groups[key] = group
    return groups


def imagers(groups: dict) -> list[str]:
    """The imagers of ``groups``: the headline's in their order, then any other (e.g. ablation variants),
    their numbers in order of value."""
    names = {k[1] for k in groups}
    return [m for m in IMAGERS if m in names] + sorted(names - set(IMAGERS), key=_natural)


def _natural(name: str) -> list:
    """Sort key that orders the numbers in a name by value (``-n168`` before ``-n1344``)."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name)]


def main_table(groups: dict) -> list[str]:
    sets = [s for s in SET_ORDER if any(k[0] == s for k in groups)]
    out = ["| set | imager | " + " | ".join(c[1] for c in COLUMNS) + " |",
           "|---|---|" + "---|" * len(COLUMNS)]
    for s in sets:
        for m in imagers(groups):
            row = groups.get((s, m))
            if row is not None:
                out.append(f"| {SET_NAMES.get(s, s)} | {NAMES.get(m, m)} (n={row['n']}) | "
                           + " | ".join(cell(row, k, d) for k, _, d in COLUMNS) + " |")
    return out


def ratio(groups: dict, other: str, model: str, key: str) -> str:
    single = next((groups[(s, model)] for s in SINGLE if (s, model) in groups), None)
    row = groups.get((other, model))
    if single is None or row is None or not single.get(key) or row.get(key) is None:
        return "-"
    return f"{row[key] / single[key]:.2f}"


def ratio_table(groups: dict) -> list[str]:
    out = ["| imager | multiple / single 2D | large / single 2D | multiple / single 3D | large / single 3D |",
           "|---|---|---|---|---|"]
    for m in imagers(groups):
        cells = [ratio(groups, o, m, k) for k in ("f1_micro_2d", "f1_micro_3d")
                 for o in ("multiple", "large")]
        if m != "average" and any(c != "-" for c in cells):       # only imagers scored beside single
            out.append(f"| {NAMES.get(m, m)} | " + " | ".join(cells) + " |")
    return out if len(out) > 2 else []


def paper_table() -> list[str]:
    out = ["| set | imager | 2D F1 | centroid mm | diameter mm |", "|---|---|---|---|---|"]
    for s, models in PAPER.items():
        for m, (diameter, com, f1) in models.items():
            out.append(f"| {s} | {m} | {f1 / 100:.3f} | {com} | {'-' if diameter is None else diameter} |")
    return out


def add_times(groups: dict, path: str) -> None:
    """Mean training seconds per imager (records ``{"imager": "img_<name>_s<seed>", "seconds": s}``)."""
    seconds: dict = {}
    for line in Path(path).read_text().splitlines():
        r = json.loads(line)
        seconds.setdefault(re.sub(r"^img_|_s\d+$", "", r["imager"]), []).append(r["seconds"])
    for (_, name), group in groups.items():
        if name in seconds:
            group["train_seconds"] = statistics.fmean(seconds[name])


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", help="less metrics --summary-only --format jsonl output")
    parser.add_argument("--no-paper", action="store_true", help="leave out the paper's numbers")
    parser.add_argument("--times", help="JSON lines of training seconds per imager: a column of them")
    args = parser.parse_args(argv)
    groups = read_groups(args.records)
    if args.times:
        add_times(groups, args.times)
        COLUMNS.append(("train_seconds", "training s", 0))
    lines = [f"Inclusion class; micro F1 over each set's scans, mean ± std over seeds (from {args.records}).",
             "", *main_table(groups)]
    if ratios := ratio_table(groups):
        lines += ["", "Generalisation: each imager's micro F1 on a set over its F1 on single.", "", *ratios]
    if not args.no_paper:
        lines += ["", "The paper's numbers (real data; 2D):", "", *paper_table()]
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1:])
