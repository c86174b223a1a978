"""Dice of `less mri-label`'s segmentation on the independent MRI phantom family (tests/mri_family.py).

Each seed draws one volume with every parameter uniform over the family's ranges (pillar 1.5-4 mm
wide and 1-15 mm tall, inclusions 6-16 mm, 1-3 of them, base up or down, any in-plane rotation,
voxels 0.4-1.2 mm, both contrasts, Rician noise 0.02-0.1, bias 0.1-0.4), labels it with
``lesscli.mri.segment.segment`` and scores it against the truth: insert Dice per volume, inclusion and
pillar Dice per inclusion (in the cell of voxels nearer to it than to the others). Prints the markdown
table of min / median per parameter band (pillar Dice only where the pillar is at least 2 voxels wide);
``--out`` keeps the rows as JSON lines. The other options draw variants of the family or score rows
written before (``--help``); docs/results/mri-label-family.md gives the runs behind its tables.

    python examples/mri_family.py --seeds 1000-1059 --out results/mri_family.jsonl
    python examples/mri_family.py --seeds 1000-1059 --partial-volume box
    python examples/mri_family.py --rows box-a.jsonl,box-b.jsonl
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

import mri_family
from mri_family import (
    MIN_INSERT_MM,
    PARTIAL_VOLUMES,
    PILLAR,
    RANGES,
    Case,
    base_error_mm,
    draw_case,
    generate,
    inclusion_scores,
    insert_scores,
    perturbed,
    pillar_voxels_wide,
    post_errors,
    tilted,
)

MIN_PILLAR_VOXELS = 2.0
LONE_SHORT_MM = (1.0, 2.5)      # --lone-short: the post's height range
NEAR_SKIN_MM = (0.5, 2.0)       # --near-skin: the highest sphere's gap to the skin
SMALL_COARSE = {"first_mm": (6.0, 7.0), "spacing_mm": (0.9, 1.2), "noise": (0.05, 0.1)}   # --small-coarse
ACCEPT = {"insert": 0.97, "inclusion": 0.93, "pillar": 0.80}


def _seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def lone_short(case):
    """``case`` with its first inclusion alone, on a post drawn 1-2.5 mm tall (seeded by the case)."""
    tall = float(np.round(np.random.default_rng([46, case.seed]).uniform(*LONE_SHORT_MM), 1))
    return dataclasses.replace(case, inclusion_mm=case.inclusion_mm[:1], pillar_height_mm=(tall,))


def small_coarse(seed: int) -> Case:
    """A volume of small spheres at coarse voxels, seeded by ``[seed // 100, seed % 100]`` (seeds 4900-4979
    and 49200-49279 are the two probes of docs/results/mri-label-rounds.md): 1-3 inclusions, the first of 6-7
    mm and the others over the
    family's range; every voxel side 0.9-1.2 mm; noise 0.05-0.1; posts, bias, base and contrast as the
    family's."""
    rng = np.random.default_rng([seed // 100, seed % 100])
    n = int(rng.integers(1, 4))
    spacing = tuple(float(v) for v in np.round(rng.uniform(*SMALL_COARSE["spacing_mm"], 3), 2))
    first = float(np.round(rng.uniform(*SMALL_COARSE["first_mm"]), 1))
    others = tuple(float(v) for v in np.round(rng.uniform(*RANGES["inclusion_mm"], n - 1), 1))
    return Case(seed=seed, spacing_mm=spacing, inclusion_mm=(first, *others),
                pillar_mm=float(np.round(rng.uniform(*RANGES["pillar_mm"]), 2)),
                pillar_height_mm=tuple(float(v)
                                       for v in np.round(rng.uniform(*RANGES["pillar_height_mm"], n), 1)),
                base_up=bool(rng.random() < 0.5), silicone_brighter=bool(rng.random() < 0.5),
                noise=float(np.round(rng.uniform(*SMALL_COARSE["noise"]), 3)),
                bias=float(np.round(rng.uniform(*RANGES["bias"]), 3)))


def near_skin(case):
    """``case`` with its highest sphere 0.5-2 mm under the skin (seeded by the case): the first inclusion's
    post raised, where it is shorter, to take its sphere there in an insert of MIN_INSERT_MM, and that sphere
    widened, where it is narrower, so that the post need not pass the family's tallest."""
    gap = float(np.round(np.random.default_rng([48, case.seed]).uniform(*NEAR_SKIN_MM), 2))
    # post plus sphere, to the gap under the skin
    reach = MIN_INSERT_MM - case.skin_mm - case.base_mm - gap

    def up(value: float, least: float) -> float:
        return max(value, math.ceil(least * 10.0 - 1e-9) / 10.0)

    wide = up(case.inclusion_mm[0], reach - RANGES["pillar_height_mm"][1])
    tall = up(case.pillar_height_mm[0], reach - wide)
    return dataclasses.replace(case, skin_gap_mm=gap, inclusion_mm=(wide, *case.inclusion_mm[1:]),
                               pillar_height_mm=(tall, *case.pillar_height_mm[1:]))


def run_case(seed: int, partial_volume: str = "ramp", floating: bool = False, lone: bool = False,
             known: bool = False, near: bool = False, small: bool = False, tilt: bool = False) -> list[dict]:
    """One volume: a case row (insert Dice, pillar voxels drawn, warnings) and one row per inclusion, each
    with the case's parameters; ``small``: drawn by :func:`small_coarse`, not ``draw_case``; ``floating``: the
    volume drawn without posts; ``lone``: :func:`lone_short`; ``near``: :func:`near_skin`; ``known``:
    segmented
    with the posts' true diameter given (``SegmentParams.pillar_diameter_mm``)."""
    from lesscli.mri.segment import SegmentParams, segment

    case = dataclasses.replace(small_coarse(seed) if small else draw_case(seed),
                               partial_volume=partial_volume)
    if floating:
        case = dataclasses.replace(case, pillar_mm=0.0)
    if lone:
        case = lone_short(case)
    if near:
        case = near_skin(case)
    if tilt:
        case = tilted(case)
    volume = generate(case)
    t0 = time.perf_counter()
    params = SegmentParams(pillar_diameter_mm=case.pillar_mm if known and case.pillar_mm > 0 else None)
    seg = segment(volume.image, volume.spacing_mm, params, where=f"seed {seed}")
    common = {"seed": seed, "voxel_mm": max(case.spacing_mm), "spacing_mm": list(case.spacing_mm),
              "pillar_mm": case.pillar_mm, "pillar_voxels": round(pillar_voxels_wide(case), 2),
              "contrast": "silicone-brighter" if case.silicone_brighter else "silicone-darker",
              "base": "up" if case.base_up else "down", "noise": case.noise, "bias": case.bias,
              "inclusions": len(case.inclusion_mm), "skin_gap_mm": case.skin_gap_mm,
              "tilt_deg": case.tilt_deg}
    base = None if seg.base_surface is None else round(base_error_mm(seg.base_surface, volume), 4)
    rows = [{"row": "case", **common, **insert_scores(seg.labels, volume),
             "base_error_mm": base, "pillar_voxels_drawn": int((seg.labels == PILLAR).sum()),
             "seconds": round(time.perf_counter() - t0, 2), "warnings": seg.warnings}]
    rows += [{"row": "inclusion", **common, **r,
              **{k: None if v is None else round(v, 4) for k, v in e.items()}}
             for r, e in zip(inclusion_scores(seg.labels, volume), post_errors(seg.posts, volume))]
    return rows


def shortfalls(case: dict, inclusions: list[dict]) -> list[str]:
    """The Dice of one volume below the acceptance (pillar only where at least 2 voxels wide)."""
    fails = [f"insert {case['dice_insert']:.3f}"] if case["dice_insert"] < ACCEPT["insert"] else []
    fails += [f"inclusion {r['dice_inclusion']:.3f}" for r in inclusions
              if r["dice_inclusion"] < ACCEPT["inclusion"]]
    fails += [f"pillar {r['dice_pillar']:.3f} ({r['pillar_voxels']} voxels)" for r in inclusions
              if r["dice_pillar"] < ACCEPT["pillar"] and r["pillar_voxels"] >= MIN_PILLAR_VOXELS]
    return fails


PERTURBATIONS = {"radius": lambda d: {"radius_mm": d}, "base": lambda d: {"base_mm": d},
                 "sphere": lambda d: {"sphere_mm": d}}


def margin_row(seed: int, deltas: list[float]) -> dict:
    """Pillar Dice per inclusion of the truth drawn with each perturbation (``perturbed``: a post's radius,
    the base's surface, a sphere's radius) of +- each delta (mm), scored against the truth as drawn: key
    ``radius+0.05`` etc."""
    case = draw_case(seed)
    truth = generate(case, image=False)
    row = {"row": "margin", "seed": seed, "pillar_voxels": round(pillar_voxels_wide(case), 2)}
    for delta in deltas:
        for name, change in PERTURBATIONS.items():
            for sign in ("+", "-"):
                moved = generate(perturbed(case, **change(delta if sign == "+" else -delta)), image=False)
                row[f"{name}{sign}{delta:g}"] = [r["dice_pillar"]
                                                 for r in inclusion_scores(moved.truth, truth)]
    return row


def margin_table(rows: list[dict], deltas: list[float]) -> str:
    """Markdown: per delta, the volumes (with pillars at least 2 voxels wide) that a perturbation of the
    truth by it alone takes below the pillar target, per perturbation and in all, with their seeds."""
    wide = [r for r in rows if r["pillar_voxels"] >= MIN_PILLAR_VOXELS]

    def below(delta, names):
        return [r["seed"] for r in wide if any(min(r[f"{n}{s}{delta:g}"]) < ACCEPT["pillar"]
                                               for n in names for s in "+-")]

    lines = [(f"Volumes with pillars at least 2 voxels wide: {len(wide)} of {len(rows)}. Below the pillar "
              f"target ({ACCEPT['pillar']}) with the truth itself moved by:"), "",
             "| perturbation (mm) | post radius +- | base surface +- | sphere radius +- | any | seeds |",
             "|---|---|---|---|---|---|"]
    for delta in deltas:
        both = below(delta, PERTURBATIONS)
        lines.append(f"| {delta:g} | {len(below(delta, ['radius']))} | {len(below(delta, ['base']))} | "
                     f"{len(below(delta, ['sphere']))} | {len(both)} | {', '.join(map(str, both))} |")
    return "\n".join(lines)


BANDS = [
    ("pillar diameter (mm)", "pillar_mm", [(1.5, 2.3), (2.3, 3.2), (3.2, 4.0)]),
    ("pillar height (mm)", "pillar_height_mm", [(1.0, 5.0), (5.0, 10.0), (10.0, 15.0)]),
    ("inclusion diameter (mm)", "inclusion_mm", [(6.0, 9.4), (9.4, 12.7), (12.7, 16.0)]),
    ("largest voxel size (mm)", "voxel_mm", [(0.4, 0.7), (0.7, 0.95), (0.95, 1.2)]),
    ("noise sigma", "noise", [(0.02, 0.047), (0.047, 0.074), (0.074, 0.1)]),
    ("bias (peak log)", "bias", [(0.1, 0.2), (0.2, 0.3), (0.3, 0.4)]),
    ("inclusions", "inclusions", [(1, 1), (2, 2), (3, 3)]),
    ("contrast", "contrast", ["silicone-darker", "silicone-brighter"]),
    ("base", "base", ["down", "up"]),
]
NEAR_SKIN_BANDS = [("highest sphere under the skin (mm)", "skin_gap_mm",
                    [(0.5, 1.0), (1.0, 1.5), (1.5, 2.0)])]
TILT_BANDS = [("insert axis tilt (degrees)", "tilt_deg", [(0.0, 3.3), (3.3, 6.7), (6.7, 10.0)])]


def _in(value, band) -> bool:
    return value == band if isinstance(band, str) else band[0] <= value <= band[1]


def _stat(values: list[float]) -> str:
    return f"{min(values):.3f} / {np.median(values):.3f}" if values else "-"


def table(rows: list[dict]) -> str:
    """Markdown: per band, n, and min / median Dice of insert, inclusion and pillar (>= 2 voxels wide)."""
    cases = [r for r in rows if r["row"] == "case"]
    incs = [r for r in rows if r["row"] == "inclusion"]
    lines = [("| parameter | band | volumes | inclusions | insert min / median | inclusion min / median "
              "| pillar (>= 2 voxels) min / median |"), "|---|---|---|---|---|---|---|"]
    near = any(r.get("skin_gap_mm") is not None for r in cases)
    tilt = any(r.get("tilt_deg") for r in cases)
    for title, key, bands in BANDS + (NEAR_SKIN_BANDS if near else []) + (TILT_BANDS if tilt else []):
        for band in bands:
            inc = [r for r in incs if _in(r[key], band)]
            pil = [r["dice_pillar"] for r in inc if r["pillar_voxels"] >= MIN_PILLAR_VOXELS]
            label = band if isinstance(band, str) else (f"{band[0]:g}" if band[0] == band[1]
                                                        else f"{band[0]:g}-{band[1]:g}")
            seeds = {i['seed'] for i in inc}
            lines.append(f"| {title} | {label} | {len({r['seed'] for r in inc})} | {len(inc)} | "
                         f"{_stat([r['dice_insert'] for r in cases if r['seed'] in seeds])} | "
                         f"{_stat([r['dice_inclusion'] for r in inc])} | {_stat(pil)} |")
    pil = [r["dice_pillar"] for r in incs if r["pillar_voxels"] >= MIN_PILLAR_VOXELS]
    thin = [r["dice_pillar"] for r in incs if 0 < r["pillar_voxels"] < MIN_PILLAR_VOXELS]
    lines.append(f"| all | - | {len(cases)} | {len(incs)} | {_stat([r['dice_insert'] for r in cases])} | "
                 f"{_stat([r['dice_inclusion'] for r in incs])} | {_stat(pil)} |")
    lines.append("")
    meeting = sum(1 for c in cases if not shortfalls(c, [r for r in incs if r["seed"] == c["seed"]]))
    decided = sum(1 for c in cases if not shortfalls({**c, "dice_insert": c["dice_insert_decided"]},
                                                     [{**r, "dice_pillar": r["dice_pillar_decided"]}
                                                      for r in incs if r["seed"] == c["seed"]]))
    floating = [c for c in cases if c["pillar_mm"] == 0]
    if floating:
        silent = sum(1 for c in floating if c["pillar_voxels_drawn"] or sum(
            "no pillar found under the inclusion" in w for w in c["warnings"]) != c["inclusions"])
        lines.append(f"Without posts: {len(floating)} volumes, {silent} with a pillar voxel drawn or an "
                     "inclusion without its warning.")
    diameters = [r["post_diameter_error_mm"] for r in incs if r.get("post_diameter_error_mm") is not None]
    if diameters:
        lines.append(f"Post diameter error: mean {np.mean(diameters):+.3f} mm, sd {np.std(diameters):.3f}, "
                     f"mean absolute {np.mean(np.abs(diameters)):.3f} ({len(diameters)} posts).")
    lines.append(f"Pillars under 2 voxels wide (not in the acceptance): {len(thin)}, Dice min / median "
                 f"{_stat(thin)}. Volumes with warnings: {sum(1 for r in cases if r['warnings'])}. "
                 f"Volumes meeting all three targets: {meeting} of {len(cases)}"
                 + (f" ({decided} with the Dice taken without the slices the box partial volume leaves "
                    "undecided at the base and the insert's outer faces)." if decided != meeting else "."))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1000-1059", help="seeds as ranges, e.g. 0-39 or 1000-1059,2000")
    parser.add_argument("--out", default=None,
                        help="JSON lines of every case and inclusion (a case's base_error_mm: how far past "
                             "the true base surface the one found lies; an inclusion's "
                             "post_diameter_error_mm, post_height_error_mm and post_offset_mm, its foot's "
                             "distance from the true axis)")
    parser.add_argument("--partial-volume", default="ramp", choices=PARTIAL_VOLUMES,
                        help="the family's partial volume: ramp (default; it adds tissue around thin posts) "
                             "or box, each voxel's share of each tissue (rows' dice_insert_decided and "
                             "dice_pillar_decided leave out the slices a flat surface leaves undecided)")
    parser.add_argument("--box-points", type=int, default=mri_family.BOX_POINTS,
                        help="sub-voxel points per axis of the box partial volume")
    parser.add_argument("--floating", action="store_true",
                        help="draw the volumes without posts: no pillar may be drawn, one warning per "
                             "inclusion (rows keep pillar_voxels_drawn)")
    drawn = parser.add_mutually_exclusive_group()
    drawn.add_argument("--lone-short", action="store_true",
                       help="draw each volume's first inclusion alone, on a post 1-2.5 mm tall (radius "
                            "fitted to all its silicone, no other post to pool with); the footer gives their "
                            "diameter error")
    drawn.add_argument("--near-skin", action="store_true",
                       help="draw each volume's highest sphere 0.5-2 mm under the skin (rows keep "
                            "skin_gap_mm)")
    parser.add_argument("--small-coarse", action="store_true",
                        help="draw small spheres at coarse voxels (the first 6-7 mm, voxels 0.9-1.2 mm, "
                             "noise 0.05-0.1; seeded by seed // 100 and seed %% 100) instead of the family's "
                             "draw")
    parser.add_argument("--tilted", action="store_true",
                        help="tilt each volume's insert axis 0-10 degrees off the array's first axis (rows "
                             "keep tilt_deg)")
    parser.add_argument("--known-diameter", action="store_true",
                        help="segment with the posts' true diameter given (less mri-label "
                             "--pillar-diameter-mm)")
    parser.add_argument("--margins", default=None,
                        help="perturbations of the truth, mm (e.g. 0.025,0.05,0.1): segment nothing, count "
                             "the volumes each takes below the pillar target")
    parser.add_argument("--rows", default=None,
                        help="rows written before with --out, comma-separated files joined: print their band "
                             "table and footer, segment nothing")
    args = parser.parse_args()
    if args.rows:
        print(table(_read_rows(args.rows.split(","))))
        return
    mri_family.BOX_POINTS = args.box_points
    rows = []
    if args.margins:
        deltas = [float(d) for d in args.margins.split(",")]
        rows = [margin_row(seed, deltas) for seed in _seeds(args.seeds)]
        _write(rows, args.out)
        print(margin_table(rows, deltas))
        return
    for seed in _seeds(args.seeds):
        new = run_case(seed, args.partial_volume, args.floating, args.lone_short, args.known_diameter,
                       args.near_skin, args.small_coarse, args.tilted)
        rows += new
        fails = shortfalls(new[0], new[1:])
        print(f"seed {seed}: {new[0]['seconds']} s" + (f"  below: {', '.join(fails)}" if fails else ""),
              file=sys.stderr, flush=True)
    _write(rows, args.out)
    print(table(rows))


def _read_rows(paths: list[str]) -> list[dict]:
    """The case and inclusion rows of ``paths`` (``--out`` files) joined; exits with one line naming a file
    that
    cannot be read or holds no case row."""
    rows = []
    for path in paths:
        try:
            with open(path) as fh:
                got = [json.loads(line) for line in fh if line.strip()]
        except (OSError, ValueError) as exc:
            sys.exit(f"mri_family.py: {path}: cannot read its rows ({exc})")
        if not any(isinstance(r, dict) and r.get("row") == "case" for r in got):
            sys.exit(f"mri_family.py: {path}: no case row (write it with --out, not --margins)")
        rows += got
    return rows


def _write(rows: list[dict], path: str | None) -> None:
    if path:
        with open(path, "w") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)


if __name__ == "__main__":
    main()
