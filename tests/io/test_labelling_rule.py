"""The labelling rule of predictions (``labels_from_probs``): thresholds on either side of 0.5."""

from __future__ import annotations

import numpy as np
import pytest

from lesscli.io.predictions import labels_from_probs

# four voxels, classes background, insert, pillar, inclusion
PROBS = np.array([[0.60, 0.05, 0.10, 0.25],     # inclusion likely, not the likeliest
                  [0.10, 0.20, 0.30, 0.40],     # inclusion the likeliest at 0.40, pillar 0.30
                  [0.05, 0.05, 0.05, 0.85],     # sure inclusion
                  [0.30, 0.50, 0.15, 0.05]]).T.reshape(4, 1, 1, 4)   # insert


@pytest.mark.parametrize("threshold, expected", [
    (None, [0, 3, 3, 1]),          # argmax
    (0.8, [0, 1, 3, 1]),           # the hand-held rule demotes the 0.40 voxel to the likelier of bg / insert
    (0.5, [0, 1, 3, 1]),
    (0.35, [0, 3, 3, 1]),          # 0.40 > 0.35: inclusion; 0.25 is not
    (0.2, [3, 3, 3, 1]),           # 0.25 > 0.2: inclusion although background is likelier
    # every voxel where pillar or inclusion has any weight, the larger of the two
    (0.0, [3, 3, 3, 2]),
])
def test_threshold_labels_a_class_exactly_where_it_exceeds_it(threshold, expected):
    got = labels_from_probs(PROBS, threshold)
    assert got.reshape(-1).tolist() == expected


def test_thresholds_at_or_above_one_half_only_demote_the_argmax():
    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(4) * 0.5, size=(3, 5, 5)).transpose(3, 0, 1, 2)
    argmax = probs.argmax(0)
    for threshold in (0.5, 0.6, 0.9):
        got = labels_from_probs(probs, threshold)
        thin = np.isin(argmax, (2, 3))
        sure = thin & (probs.max(0) > threshold)
        assert (got[sure] == argmax[sure]).all()
        assert np.isin(got[~sure], (0, 1)).all()
        assert (got[~thin] == argmax[~thin]).all()


def test_the_menu_masks_are_the_rule_applied_rule_by_rule():
    """``choose_labelling`` reuses each smoothing and threshold across rules: the same masks as one
    ``labels_from_probs`` call per rule."""
    from lesscli.train.image_fit import (
        MIN_VOLUME_CHOICES_MM3,
        SMOOTH_CHOICES_MM,
        THRESHOLD_CHOICES,
        _menu_masks,
    )

    rng = np.random.default_rng(3)
    logits = rng.normal(0, 1.5, (4, 5, 24, 24))
    logits[3, 1:4, 6:14, 8:15] += 3.0
    probs = np.exp(logits) / np.exp(logits).sum(0)
    spacing = (1.8, 0.95, 0.95)
    choices = [(sm, th, float(mv)) for sm in SMOOTH_CHOICES_MM for th in THRESHOLD_CHOICES
               for mv in MIN_VOLUME_CHOICES_MM3]
    masks = list(_menu_masks(probs, choices, spacing))
    assert len(masks) == len(choices) and len({m.tobytes() for m in masks}) > 10
    for (sm, th, mv), mask in zip(choices, masks):
        np.testing.assert_array_equal(mask, labels_from_probs(probs, th, mv, spacing, sm) == 3)
