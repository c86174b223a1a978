"""Imaging metrics: agreement with scikit-learn (and MONAI when present), and hypothesis properties."""

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lesscli.metrics import confusion, dice, f1_from, precision_from, recall_from, score_masks, summarise
from lesscli.metrics.masks import all_pairs_diameter_mm, diameter_mm
from lesscli.metrics.volume import METRICS_2D, METRICS_3D

BOUNDED = {"f1": (0, 1), "precision": (0, 1), "recall": (0, 1), "arse": (0, 2)}
SYMMETRIC_3D = ("f1_3d", "com_error_mm_3d", "arse_3d", "diameter_error_mm_3d", "volume_error_mm3")


def test_importing_metrics_does_not_import_torch():
    code = "import sys, lesscli.metrics, lesscli.cli.metrics; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("seed", range(6))
def test_f1_precision_recall_agree_with_sklearn(seed):
    from sklearn.metrics import f1_score, precision_score, recall_score

    rng = np.random.default_rng(seed)
    p_incl = [0.0, 0.02, 0.3, 0.7][seed % 4]
    truth = np.where(rng.random((3, 9, 11)) < 0.1 + 0.1 * (seed % 3), 3, rng.integers(0, 3, (3, 9, 11)))
    pred = np.where(rng.random((3, 9, 11)) < p_incl, 3, rng.integers(0, 3, (3, 9, 11)))
    tp, fp, fn = confusion(pred == 3, truth == 3)
    y, p = (truth == 3).ravel(), (pred == 3).ravel()
    assert f1_from(tp, fp, fn) == pytest.approx(f1_score(y, p, zero_division=np.nan))
    if p.any():
        assert precision_from(tp, fp, fn) == pytest.approx(precision_score(y, p))
    else:
        assert precision_from(tp, fp, fn) is None
    assert recall_from(tp, fp, fn) == pytest.approx(recall_score(y, p))


def test_micro_f1_over_a_set_agrees_with_sklearn_on_the_concatenation():
    from sklearn.metrics import f1_score

    rng = np.random.default_rng(7)
    pairs = [(rng.random((2, 8, 8)) < 0.2, rng.random((2, 8, 8)) < q) for q in (0.1, 0.3, 0.0, 0.5)]
    rows = [score_masks(p, t, np.zeros(3), np.ones(3)) for p, t in pairs]
    (summary,) = summarise(rows)
    expected = f1_score(np.concatenate([t.ravel() for _, t in pairs]),
                        np.concatenate([p.ravel() for p, _ in pairs]))
    assert summary["f1_micro_3d"] == pytest.approx(expected)
    assert summary["f1_3d"] == pytest.approx(np.mean([r["f1_3d"] for r in rows if r["f1_3d"] is not None]))


def test_dice_agrees_with_monai():
    torch = pytest.importorskip("torch")
    monai_metrics = pytest.importorskip("monai.metrics")
    rng = np.random.default_rng(3)
    a, b = rng.random((4, 10, 10)) < 0.3, rng.random((4, 10, 10)) < 0.4
    ours = dice(a, b)
    theirs = monai_metrics.compute_dice(torch.as_tensor(a[None, None]).float(),
                                        torch.as_tensor(b[None, None]).float(), include_background=True)
    assert ours == pytest.approx(float(theirs.reshape(-1)[0]))


# --------------------------------------------------------------------------------------- hypothesis

masks = arrays(np.bool_, st.tuples(st.integers(1, 4), st.integers(1, 7), st.integers(1, 7)),
               elements=st.booleans())
spacings = st.tuples(*[st.floats(0.1, 3.0) for _ in range(3)]).map(np.array)


@st.composite
def mask_pairs(draw):
    a = draw(masks)
    b = draw(arrays(np.bool_, a.shape, elements=st.booleans()))
    return a, b


def _check_value(key, value):
    if value is None or isinstance(value, bool):
        return
    assert math.isfinite(value), key
    for prefix, (lo, hi) in BOUNDED.items():
        if key.startswith(prefix + "_"):
            assert lo - 1e-12 <= value <= hi + 1e-12, (key, value)
    if "error" in key or "diameter" in key or key.startswith(("area", "volume")):
        assert value >= 0, key


@settings(max_examples=60, deadline=None)
@given(mask_pairs(), spacings)
def test_metrics_are_finite_or_explicitly_undefined(pair, spacing):
    row = score_masks(pair[0], pair[1], np.array([-3.0, 1.0, 2.0]), spacing)
    expected = set(METRICS_2D) | (set(METRICS_3D) if pair[0].shape[0] > 1 else set())
    assert expected <= set(row)
    for key, value in row.items():
        _check_value(key, value)


@settings(max_examples=60, deadline=None)
@given(mask_pairs(), spacings)
def test_3d_metrics_are_symmetric(pair, spacing):
    a, b = pair
    if a.shape[0] < 2:
        return
    ab, ba = score_masks(a, b, np.zeros(3), spacing), score_masks(b, a, np.zeros(3), spacing)
    for key in SYMMETRIC_3D:
        if ab[key] is None:
            assert ba[key] is None, key
        else:
            assert ba[key] == pytest.approx(ab[key], abs=1e-9), key
    assert ab["precision_3d"] == ba["recall_3d"] and ab["recall_3d"] == ba["precision_3d"]
    assert dice(a, b) == dice(b, a)


@settings(max_examples=60, deadline=None)
@given(mask_pairs(), spacings, st.tuples(*[st.integers(0, 3) for _ in range(3)]),
       st.tuples(*[st.floats(-50, 50) for _ in range(3)]).map(np.array))
def test_invariant_to_translating_both_volumes(pair, spacing, offset, origin_shift):
    a, b = pair
    big = tuple(s + 3 for s in a.shape)
    a2, b2 = np.zeros(big, bool), np.zeros(big, bool)
    window = tuple(slice(o, o + s) for o, s in zip(offset, a.shape))
    a2[window], b2[window] = a, b
    base = score_masks(a, b, np.zeros(3), spacing)
    moved = score_masks(a2, b2, origin_shift, spacing)
    for key, value in base.items():
        if key in ("slice_2d", "slice_z_mm"):
            continue
        if value is None or isinstance(value, (bool, int)):
            assert moved[key] == value, key
        else:
            assert moved[key] == pytest.approx(value, abs=1e-9), key
    if base["slice_2d"] is not None:
        assert moved["slice_2d"] == base["slice_2d"] + offset[0]


def _corner_reference(mask, spacing):
    """Brute force: all corners of all pixels, all pairs, max over slices."""
    from scipy.spatial.distance import pdist

    best = None
    for sl in mask:
        idx = np.argwhere(sl).astype(float)
        if len(idx):
            pts = np.concatenate([idx + [di, dj] for di in (-0.5, 0.5) for dj in (-0.5, 0.5)]) * spacing[1:]
            d = float(pdist(pts).max())
            best = d if best is None else max(best, d)
    return best


@settings(max_examples=40, deadline=None)
@given(masks, spacings)
def test_hull_diameter_equals_all_pairs(mask, spacing):
    if not mask.any():
        assert diameter_mm(mask, spacing) is None and diameter_mm(mask, spacing, "corners") is None
        return
    assert diameter_mm(mask, spacing) == pytest.approx(all_pairs_diameter_mm(mask, spacing), abs=1e-9)
    assert diameter_mm(mask, spacing, "corners") == pytest.approx(_corner_reference(mask, spacing), abs=1e-9)
