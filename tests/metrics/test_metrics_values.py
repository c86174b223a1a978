"""Imaging metrics against hand-computed values: spheres, boxes, shifts, anisotropic grids, empties."""

import math

import numpy as np
import pytest
from factories import sphere_labels

from lesscli.io.labels import INCLUSION, INSERT, PILLAR, LabelVolume
from lesscli.metrics import (
    average_baseline,
    centroid_mm,
    diameter_mm,
    dice,
    score_baseline,
    score_labels,
    score_masks,
    slice_diameters_mm,
    summarise,
)
from lesscli.metrics.masks import all_pairs_diameter_mm


def box(shape, lo, hi):
    """Boolean (D, H, W) mask with ones on [lo, hi) along each axis."""
    mask = np.zeros(shape, bool)
    mask[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    return mask


def ball(shape, centre, radius_vox):
    k, i, j = np.indices(shape)
    return (k - centre[0]) ** 2 + (i - centre[1]) ** 2 + (j - centre[2]) ** 2 <= radius_vox**2


# ------------------------------------------------------------------------------------------- geometry

def test_sphere_of_radius_two_voxels_on_a_unit_grid():
    # Voxels with i^2 + j^2 + k^2 <= 4: 1 + 6 + 12 + 8 + 6 = 33; the equator has 13 pixels.
    mask = ball((11, 11, 11), (5, 5, 5), 2)
    origin, spacing = np.array([-10.0, 3.0, 7.0]), np.ones(3)
    row = score_masks(mask, mask, origin, spacing)
    assert row["volume_true_mm3"] == 33.0
    assert row["diameter_true_mm_3d"] == pytest.approx(4.0)
    np.testing.assert_allclose(centroid_mm(mask, origin, spacing), [-5.0, 8.0, 12.0])
    assert row["slice_2d"] == 5 and row["slice_z_mm"] == -5.0 and row["area_true_mm2"] == 13.0
    # (-2.5, -0.5) to (2.5, 0.5)
    assert diameter_mm(mask, spacing, "corners") == pytest.approx(math.sqrt(26.0))
    assert row["f1_3d"] == 1.0 and row["com_error_mm_3d"] == 0.0 and row["diameter_error_mm_3d"] == 0.0


def test_sphere_of_16_mm_on_the_default_grid():
    vol = sphere_labels(center_mm=(-11.0, 2.0, -3.0), radius_mm=8.0)
    row = score_labels(vol.data, vol.data, vol.origin_mm, vol.spacing_mm)
    dx = vol.spacing_mm[2]
    assert 16.0 - 2 * dx <= row["diameter_true_mm_3d"] <= 16.0
    assert row["volume_true_mm3"] == pytest.approx(4 / 3 * math.pi * 8.0**3, rel=0.03)
    np.testing.assert_allclose(centroid_mm(vol.data == INCLUSION, vol.origin_mm, vol.spacing_mm),
                               [-11.0, 2.0, -3.0], atol=0.05)
    assert (row["diameter_true_mm_3d"]
            == pytest.approx(all_pairs_diameter_mm(vol.data == INCLUSION, vol.spacing_mm)))


@pytest.mark.parametrize("points, expected", [("centres", 1.25), ("corners", math.sqrt(3.25))])
def test_box_on_an_anisotropic_grid(points, expected):
    # 2 x 3 x 4 voxels at (dz, dy, dx) = (2, 0.5, 0.25): slice diagonal (1.0, 0.75) or (1.5, 1.0) mm.
    spacing, origin = np.array([2.0, 0.5, 0.25]), np.array([1.0, -2.0, 4.0])
    mask = box((5, 8, 9), (1, 2, 3), (3, 5, 7))
    row = score_masks(mask, mask, origin, spacing, points)
    assert row["diameter_true_mm_3d"] == pytest.approx(expected)
    assert row["volume_true_mm3"] == pytest.approx(24 * 0.25)
    assert row["slice_2d"] == 1 and row["area_true_mm2"] == pytest.approx(12 * 0.125)
    np.testing.assert_allclose(centroid_mm(mask, origin, spacing), origin + spacing * [1.5, 3.0, 4.5])


@pytest.mark.parametrize("pixels, spacing, points, expected", [
    ([(0, 0)], (1.0, 0.5, 0.3), "centres", 0.0),
    ([(0, 0)], (1.0, 0.5, 0.3), "corners", math.hypot(0.5, 0.3)),
    ([(2, 1), (2, 2), (2, 3), (2, 4), (2, 5)], (1.0, 0.5, 0.3), "centres", 4 * 0.3),   # a row: collinear
    ([(1, 2), (2, 2), (3, 2), (4, 2)], (1.0, 0.5, 0.3), "centres", 3 * 0.5),          # a column
    ([(0, 0), (1, 1), (2, 2), (3, 3)], (1.0, 1.0, 1.0), "centres", 3 * math.sqrt(2)),  # a diagonal
    ([(0, 0), (0, 5), (5, 0), (5, 5), (2, 3)], (1.0, 1.0, 2.0), "centres", math.hypot(5, 10)),
])
def test_slice_diameter_small_cases(pixels, spacing, points, expected):
    mask = np.zeros((1, 7, 7), bool)
    for i, j in pixels:
        mask[0, i, j] = True
    assert slice_diameters_mm(mask, np.array(spacing), points)[0] == pytest.approx(expected)


def test_diameter_is_max_over_slices_ignoring_empty_ones():
    mask = np.zeros((4, 9, 9), bool)
    mask[0, 4, 2:5] = True     # 2 mm
    mask[2, 1:8, 4] = True     # 6 mm
    per = slice_diameters_mm(mask, np.ones(3))
    assert np.isnan(per[1]) and np.isnan(per[3])
    assert diameter_mm(mask, np.ones(3)) == 6.0  # not the mean over slices (the published code's bug)


# ------------------------------------------------------------------------------------------ shifts

SPACING = np.array([0.9, 0.4774, 0.4774])


@pytest.mark.parametrize("shift", [(0, 0, 3), (0, -2, 0), (1, 0, 0), (1, -2, 3), (-2, 4, 1)])
def test_shifted_prediction_com_error_is_the_shift(shift):
    truth = ball((14, 30, 30), (7, 15, 15), 4)
    pred = np.roll(truth, shift, axis=(0, 1, 2))
    row = score_masks(pred, truth, np.zeros(3), SPACING)
    step_mm = np.array(shift) * SPACING
    assert row["com_error_mm_3d"] == pytest.approx(np.linalg.norm(step_mm), abs=1e-12)
    assert row["com_error_mm_2d"] == pytest.approx(np.linalg.norm(step_mm[1:]), abs=1e-12)  # in-plane only
    assert row["diameter_error_mm_3d"] == pytest.approx(0.0, abs=1e-12)
    assert row["volume_error_mm3"] == 0.0 and row["arse_3d"] == 0.0


# ----------------------------------------------------------------------------------- two inclusions

def test_two_inclusions_area_error():
    spacing = np.array([1.5, 0.5, 0.5])
    truth = np.zeros((3, 10, 12), bool)
    truth[1, 1:4, 1:4] = True   # 9 pixels, centroid (2, 2)
    truth[1, 6:8, 8:10] = True  # 4 pixels, centroid (6.5, 8.5)
    pred = np.zeros_like(truth)
    pred[1, 1:4, 1:4] = True
    row = score_masks(pred, truth, np.zeros(3), spacing)
    assert row["area_error_mm2"] == pytest.approx(4 * 0.25)
    assert row["volume_error_mm3"] == pytest.approx(4 * 0.375)
    assert row["arse_2d"] == pytest.approx(4 / 11)
    assert (row["precision_2d"], row["recall_2d"], row["f1_2d"]) == pytest.approx((1.0, 9 / 13, 18 / 22))
    assert row["com_error_mm_2d"] == pytest.approx(0.5 * math.hypot(18 / 13, 26 / 13))
    assert row["diameter_true_mm_2d"] == pytest.approx(0.5 * math.hypot(6, 8))
    assert row["diameter_error_mm_2d"] == pytest.approx(5.0 - math.sqrt(2))


# -------------------------------------------------------------------------------------- empty masks

FULL = box((3, 6, 6), (0, 1, 1), (2, 4, 5))   # 2 x 3 x 4 = 24 voxels, 12 per slice
EMPTY = np.zeros((3, 6, 6), bool)
UNIT = np.ones(3)


@pytest.mark.parametrize("pred, truth, expected", [
    (FULL, FULL, {"precision_3d": 1.0, "recall_3d": 1.0, "f1_3d": 1.0, "arse_3d": 0.0, "com_error_mm_3d": 0.0,
                  "diameter_error_mm_3d": 0.0, "volume_error_mm3": 0.0, "f1_2d": 1.0, "area_error_mm2": 0.0}),
    (EMPTY, FULL,
     {"precision_3d": None, "recall_3d": 0.0, "f1_3d": 0.0, "arse_3d": 2.0, "com_error_mm_3d": None,
                   "diameter_error_mm_3d": None, "volume_error_mm3": 24.0, "f1_2d": 0.0, "precision_2d": None,
                   "com_error_mm_2d": None, "area_error_mm2": 12.0, "slice_2d": 0}),
    (FULL, EMPTY,
     {"precision_3d": 0.0, "recall_3d": None, "f1_3d": 0.0, "arse_3d": 2.0, "com_error_mm_3d": None,
                   "diameter_error_mm_3d": None, "volume_error_mm3": 24.0, "f1_2d": None,
                   "area_error_mm2": None, "slice_2d": None, "truth_empty_2d": True}),
    (EMPTY, EMPTY, {"precision_3d": None, "recall_3d": None, "f1_3d": None, "arse_3d": None,
                    "com_error_mm_3d": None, "diameter_error_mm_3d": None, "volume_error_mm3": 0.0,
                    "f1_2d": None, "area_error_mm2": None, "truth_empty_3d": True, "pred_empty_3d": True}),
], ids=["both", "pred-empty", "truth-empty", "neither"])
def test_empty_rules(pred, truth, expected):
    row = score_masks(pred, truth, np.zeros(3), UNIT)
    for key, value in expected.items():
        assert row[key] == value, key


def test_dice_of_two_empty_masks_is_undefined_not_perfect():
    assert dice(EMPTY, EMPTY) is None and dice(FULL, EMPTY) == 0.0 and dice(FULL, FULL) == 1.0


def test_depth_one_volume_gets_only_2d_metrics():
    mask = box((1, 6, 6), (0, 1, 1), (1, 4, 4))
    row = score_masks(mask, mask, np.zeros(3), UNIT)
    assert "f1_3d" not in row and "volume_error_mm3" not in row
    assert row["f1_2d"] == 1.0 and row["area_true_mm2"] == 9.0 and row["slice_2d"] == 0


def test_pillar_class_is_scored_on_request():
    truth = np.full((3, 6, 6), INSERT, np.uint8)
    truth[:, 2, 2] = PILLAR
    pred = truth.copy()
    pred[0, 2, 2] = INSERT
    row = score_labels(pred, truth, np.zeros(3), UNIT, cls="pillar")
    assert row["recall_3d"] == pytest.approx(2 / 3) and row["precision_3d"] == 1.0
    assert score_labels(pred, truth, np.zeros(3), UNIT)["f1_3d"] is None  # no inclusion anywhere


# ----------------------------------------------------------------------------------------- baseline

def _label_box(lo, hi, shape=(4, 12, 12), spacing=(1.0, 1.0, 1.0)):
    data = np.full(shape, INSERT, np.uint8)
    data[box(shape, lo, hi)] = INCLUSION
    return LabelVolume(data, np.zeros(3), np.array(spacing))


def test_average_baseline_predicts_the_training_mean():
    # Boxes in slices 1..2: 3x3 (diameter 2 sqrt 2, centroid (1.5, 2, 2)) and 5x5 (4 sqrt 2, (1.5, 6, 6)).
    train = [_label_box((1, 1, 1), (3, 4, 4)), _label_box((1, 4, 4), (3, 9, 9)), LabelVolume(
        np.full((4, 12, 12), INSERT, np.uint8), np.zeros(3), np.ones(3))]
    base = average_baseline(train)
    assert (base.n_volumes, base.n_empty) == (2, 1)
    assert base.diameter_mm_3d == pytest.approx(3 * math.sqrt(2))
    np.testing.assert_allclose(base.centroid_mm_3d, [1.5, 4.0, 4.0])
    np.testing.assert_allclose(base.centroid_mm_2d, [4.0, 4.0])
    # 2 x 4 pixels in slice 0: diameter hypot(1, 3), centroid (0, 2.5, 3.5)
    test = _label_box((0, 2, 2), (1, 4, 6))
    row = score_baseline(base, test.data, test.origin_mm, test.spacing_mm)
    assert row["diameter_error_mm_3d"] == pytest.approx(abs(3 * math.sqrt(2) - math.hypot(1, 3)))
    assert row["com_error_mm_3d"] == pytest.approx(math.sqrt(1.5**2 + 1.5**2 + 0.5**2))
    assert row["com_error_mm_2d"] == pytest.approx(math.hypot(1.5, 0.5))
    empty = score_baseline(base, np.full((4, 12, 12), INSERT, np.uint8), np.zeros(3), np.ones(3))
    assert empty["com_error_mm_3d"] is None and empty["diameter_error_mm_2d"] is None


def test_average_baseline_is_scored_as_the_mean_sphere_painted_on_the_truth_grid():
    train = [_label_box((1, 1, 1), (3, 4, 4)), _label_box((1, 4, 4), (3, 9, 9))]
    base = average_baseline(train)          # centre (1.5, 4, 4) mm, diameter 3 sqrt 2: radius^2 4.5
    test = _label_box((0, 2, 2), (1, 4, 6))
    row = score_baseline(base, test.data, test.origin_mm, test.spacing_mm)
    inside = [(z, y, x) for z in range(4) for y in range(12) for x in range(12)
              if (z - 1.5) ** 2 + (y - 4) ** 2 + (x - 4) ** 2 <= 4.5]
    truth = {(0, y, x) for y in (2, 3) for x in (2, 3, 4, 5)}
    tp = len(truth.intersection(inside))                    # (0, 3, 3), (0, 3, 4), (0, 3, 5)
    # 9 voxels in each of slices 0 and 3 (dy^2 + dx^2 <= 2.25), 13 in slices 1 and 2 (<= 4.25)
    assert (row["tp_3d"], row["fp_3d"], row["fn_3d"]) == (tp, len(inside) - tp,
                                                          len(truth) - tp) == (3, 44 - 3, 5)
    assert row["f1_3d"] == pytest.approx(2 * 3 / (2 * 3 + 41 + 5))
    # 2D: the mean disc (centre (4, 4), the mean largest-slice diameter) on the truth's largest slice 0
    d2 = base.diameter_mm_2d
    disc = {(y, x) for y in range(12) for x in range(12) if (y - 4) ** 2 + (x - 4) ** 2 <= (d2 / 2) ** 2}
    tp2 = len({(y, x) for _, y, x in truth} & disc)
    assert (row["tp_2d"], row["fp_2d"], row["fn_2d"]) == (tp2, len(disc) - tp2, 8 - tp2)
    empty = score_baseline(base, np.full((4, 12, 12), INSERT, np.uint8), np.zeros(3), np.ones(3))
    assert (empty["tp_3d"], empty["fn_3d"], empty["f1_3d"]) == (0, 0, 0.0) and empty["f1_2d"] is None


# ----------------------------------------------------------------------------------------- summaries

def test_summarise_mean_std_and_valid_counts():
    rows = [{"model": "a", "f1_3d": 0.5, "com_error_mm_3d": None, "tp_3d": 1, "fp_3d": 1, "fn_3d": 0},
            {"model": "a", "f1_3d": 0.7, "com_error_mm_3d": 2.0, "tp_3d": 3, "fp_3d": 0, "fn_3d": 2},
            {"model": "a", "f1_3d": None, "com_error_mm_3d": 4.0, "tp_3d": 0, "fp_3d": 0, "fn_3d": 0},
            {"model": "b", "f1_3d": 0.1, "com_error_mm_3d": None, "tp_3d": 0, "fp_3d": 3, "fn_3d": 0}]
    a, b = summarise(rows, ("model",))
    assert a["n"] == 3 and a["f1_3d"] == pytest.approx(0.6) and a["f1_3d_n"] == 2
    assert a["f1_3d_std"] == pytest.approx(np.std([0.5, 0.7], ddof=1))
    assert a["com_error_mm_3d"] == 3.0 and a["com_error_mm_3d_n"] == 2
    assert a["f1_micro_3d"] == pytest.approx(2 * 4 / (2 * 4 + 1 + 2)) and a["precision_micro_3d"] == 0.8
    assert b["f1_3d_std"] is None and b["com_error_mm_3d"] is None and b["com_error_mm_3d_n"] == 0
    assert b["recall_micro_3d"] is None and b["f1_micro_3d"] == 0.0
