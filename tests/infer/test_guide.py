"""Touch guidance: greedy entropy coverage, outline masks, the CLI, and the closed-loop helpers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from factories import random_scanset
from imaging_factory import save_tiny_imager, tiny_imager

from lesscli.infer.guide import (
    GuideOptions,
    disc_kernel,
    footprint_mask,
    guide_scan,
    octagon_mask,
    pixel_centres_mm,
    suggest_touches,
)
from lesscli.types import ImageGrid

GRID = ImageGrid((1, 61, 61), (0.0, -30.0, -30.0), (0.9, 1.0, 1.0))     # 1 mm pixels, x = y = 0 at [30, 30]


def blob(x_mm: float, y_mm: float, sigma_mm: float, height: float) -> np.ndarray:
    x, y = pixel_centres_mm(GRID)
    return height * np.exp(-((x - x_mm) ** 2 + (y - y_mm) ** 2) / (2 * sigma_mm**2))


def test_disc_kernel_hand_counted():
    assert disc_kernel(1.0, (1.0, 1.0)).sum() == 5                  # centre + 4 neighbours
    assert disc_kernel(1.5, (1.0, 1.0)).sum() == 9                  # the 3 x 3 square (diagonal 1.41 < 1.5)
    assert disc_kernel(2.0, (1.0, 2.0)).shape == (5, 3)


def test_greedy_picks_the_largest_uncertainty_first_and_spreads():
    ent = blob(-15, 10, 3, 1.0) + blob(12, -8, 3, 0.35) + blob(14, -4, 3, 0.33)
    allowed = np.ones((61, 61), bool)
    rows = suggest_touches(ent, GRID, allowed, GuideOptions(k=3, radius_mm=5.0, exclusion_mm=10.0), 10.0)
    assert (rows[0]["x_mm"], rows[0]["y_mm"]) == (-15.0, 10.0)
    second = np.array([rows[1]["x_mm"], rows[1]["y_mm"]])
    assert np.hypot(*(second - [13, -6])) < 3.0                    # between the two overlapping blobs
    pts = np.array([[r["x_mm"], r["y_mm"]] for r in rows])
    gaps = np.hypot(*(pts[:, None] - pts[None]).transpose(2, 0, 1))[np.triu_indices(3, 1)]
    assert gaps.min() >= 10.0
    covered = [r["entropy_covered_nats_mm2"] for r in rows]
    assert covered == sorted(covered, reverse=True) and covered[0] > 0


def test_suggestions_stay_in_the_allowed_region_and_stop_when_it_is_used_up():
    ent = blob(25, 25, 3, 1.0) + blob(0, 0, 3, 0.2)
    allowed = octagon_mask(GRID, 60.0, 3.0)
    x, y = pixel_centres_mm(GRID)
    assert not allowed[(x == 29) & (y == 29)].any() and allowed[(x == 0) & (y == 0)].all()
    rows = suggest_touches(ent, GRID, allowed, GuideOptions(k=50, radius_mm=5.0, exclusion_mm=20.0), 10.0)
    assert all(allowed[int(r["y_mm"] + 30), int(r["x_mm"] + 30)] for r in rows)
    assert 3 <= len(rows) < 50                                     # the exclusion zones exhaust the octagon


def test_footprint_mask_erodes_by_the_margin():
    labels = np.zeros((2, 61, 61), np.uint8)
    labels[1, 10:51, 10:51] = 1                                    # x, y in [-20, 20] mm
    mask = footprint_mask(labels, GRID, 4.0)
    x, y = pixel_centres_mm(GRID)
    assert mask[(np.abs(x) <= 15) & (np.abs(y) <= 15)].all()
    assert not mask[(np.abs(x) > 16) | (np.abs(y) > 16)].any()


def test_guide_scan_points_away_from_touched_regions():
    imager, stats, config = tiny_imager()
    scans = random_scanset(n_scans=1, traj_per_scan=30, max_len=8, seed=3, with_labels=False)
    rng = np.random.default_rng(0)
    scans.pose[:, 0] = -rng.uniform(6, 24, scans.n_steps)          # every touch on the left (x <= -6 mm)
    g = guide_scan(imager, {"config": config, "norm_stats": stats}, scans, 0, GuideOptions(k=3))
    assert len(g.rows) == 3
    assert g.rows[0]["x_mm"] > 0 and g.rows[1]["x_mm"] > 0        # the untouched right half is most uncertain
    x, _ = pixel_centres_mm(g.grid)
    touched = g.entropy[0][(x > -20) & (x < -8)].mean()
    assert g.rows[0]["mean_entropy_nats"] > touched + 0.2


def test_guide_cli_lines_and_overlay(tmp_path, run_less):
    from lesscli.io.scans import save_scans

    save_tiny_imager(str(tmp_path / "im.pt"))
    save_scans(str(tmp_path / "p.npz"), random_scanset(n_scans=2, traj_per_scan=3, max_len=6, seed=5))
    proc = run_less("guide", "im.pt", "p.npz", "--scan", "1", "--k", "3", "--plot", "ov.png", "--score",
                    "inclusion", check=True)
    rows = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert [r["rank"] for r in rows] == [1, 2, 3] and {r["scan"] for r in rows} == {1}
    assert (tmp_path / "ov.png").stat().st_size > 1000
    bad = run_less("guide", "im.pt", "p.npz", "--plot", "x.png")
    assert bad.returncode == 2 and "--scan" in bad.stderr.decode() and not (tmp_path / "x.png").exists()


def test_closed_loop_helpers():
    from lesscli.bench.guide import first_reach, mean_curves, raster_points, touches_to_reach

    pts = raster_points(60)
    assert abs(len(pts) - 60) <= 8
    order = np.lexsort((pts[:, 0], pts[:, 1]))
    assert np.array_equal(order, np.arange(len(pts)))             # row by row, x increasing in a row
    curve = [(3, 0.1), (6, 0.5), (9, 0.7)]
    assert touches_to_reach(curve, 0.5) == 6 and touches_to_reach(curve, 0.8) is None
    assert touches_to_reach([(3, 0.6), (6, 0.4), (9, 0.6)], 0.5) == 9     # it must stay above the target
    assert first_reach([(3, 0.6), (6, 0.4), (9, 0.6)], 0.5) == 3
    means = mean_curves({"a": [curve, [(3, 0.3), (6, 0.7), (9, 0.9)]]})
    assert means["a"] == [(3, pytest.approx(0.2)), (6, pytest.approx(0.6)), (9, pytest.approx(0.8))]


def test_guide_summary_compares_touch_counts_only_when_raster_gains():
    from lesscli.bench.guide import GuideBench, summary_row

    bench = GuideBench(budget=9, start=3, seeds=1, eval_every=3, batch=1, seed=0)
    learned = {"guided": [(3, 0.1), (6, 0.6), (9, 0.7)], "guided-inclusion": [(3, 0.1), (6, 0.2), (9, 0.6)],
               "raster": [(3, 0.1), (6, 0.3), (9, 0.6)], "random": [(3, 0.1), (6, 0.2), (9, 0.3)]}
    row = summary_row(learned, bench, "m.pt")
    assert row["raster_final_f1"] == 0.6 and row["guided_touches_to_raster_final"] == 6
    assert row["guided_saving"] == pytest.approx(1 - 6 / 9) and row["random_touches_to_raster_final"] is None
    assert row["guided_inclusion_touches_to_raster_final"] == 9 and "note" not in row
    # a model that images nothing: raster ends where every strategy started, so nothing is compared
    blind = {s: [(3, 0.002), (6, 0.0), (9, 0.0)] for s in learned}
    row = summary_row(blind, bench, "m.pt")
    assert row["guided_touches_to_raster_final"] is None and row["guided_saving"] is None
    assert row["guided_first_reaches_raster_final"] is None and row["random_touches_to_raster_final"] is None
    assert "nothing to reach" in row["note"]


def test_uncertainty_scores_hand_values():
    from lesscli.infer.guide import UNCERTAINTY

    uniform = np.full((4, 1, 2), 0.25)
    assert np.allclose(UNCERTAINTY["entropy"](uniform), np.log(4))
    assert np.allclose(UNCERTAINTY["inclusion"](uniform), -(0.25 * np.log(0.25) + 0.75 * np.log(0.75)))
    half = np.array([0.25, 0.25, 0.0, 0.5])[:, None]
    assert np.allclose(UNCERTAINTY["inclusion"](half), np.log(2))          # the maximum: inclusion or not?
    sure = np.array([0.0, 1.0, 0.0, 0.0])[:, None]
    assert np.allclose(UNCERTAINTY["entropy"](sure), 0.0) and np.allclose(UNCERTAINTY["inclusion"](sure), 0.0)
