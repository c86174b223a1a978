"""`less mri-label` on the independent MRI phantom family (tests/mri_family.py), table-driven.

The rows span the family's ranges by design (pillar 1.5-4 mm wide and 1-15 mm tall, inclusions 6-16 mm,
1-3 of them, base up or down, rotations, voxels 0.4-1.2 mm anisotropic, both contrasts, noise
0.02-0.1, bias 0.1-0.4); their seeds are not among those the segmentation was tuned on (0-99 of
``draw_case``). Acceptance: Dice insert >= 0.97, inclusion >= 0.93 and, where the pillar is at least 2
voxels wide, pillar >= 0.80, per inclusion. The wide sweep behind the table of
docs/results/mri-label-family.md is ``examples/mri_family.py``.
"""

from __future__ import annotations

import json
import math

import nibabel as nib
import numpy as np
import pytest
from mri_family import (
    INCLUSION,
    INSERT,
    PILLAR,
    Case,
    base_error_mm,
    draw_case,
    generate,
    inclusion_scores,
    insert_scores,
    perturbed,
    pillar_voxels_wide,
    post_errors,
    scores,
)

from lesscli.mri.segment import segment

MIN_DICE = {"insert": 0.97, "inclusion": 0.93, "pillar": 0.80}
MIN_PILLAR_VOXELS = 2.0

CASES = {
    "fine-voxels-1.5mm-pillar-15mm-tall-6mm-dark-noisy-base-up": Case(
        seed=500, spacing_mm=(0.45, 0.42, 0.42), inclusion_mm=(6.0,), pillar_mm=1.5, pillar_height_mm=(15.0,),
        base_up=True, noise=0.1, bias=0.4),
    "coarse-1.2mm-4mm-pillar-1mm-tall-16mm-bright": Case(
        seed=501, spacing_mm=(1.2, 1.2, 1.2), inclusion_mm=(16.0,), pillar_mm=4.0, pillar_height_mm=(1.0,),
        silicone_brighter=True, noise=0.02, bias=0.1),
    "three-inclusions-anisotropic-bright-base-up": Case(
        seed=502, spacing_mm=(1.2, 0.5, 0.8), inclusion_mm=(6.5, 11.0, 16.0), pillar_mm=2.5,
        pillar_height_mm=(14.0, 8.0, 2.0), base_up=True, silicone_brighter=True, noise=0.06, bias=0.3,
        yaw_deg=37.0),
    "two-inclusions-thick-slices-dark-noisy": Case(
        seed=503, spacing_mm=(1.2, 0.6, 0.6), inclusion_mm=(8.0, 14.0), pillar_mm=3.0,
        pillar_height_mm=(3.0, 12.0), noise=0.1, bias=0.25),
    "2mm-pillar-2.2-voxels-strong-bias": Case(
        seed=504, spacing_mm=(0.5, 0.9, 0.9), inclusion_mm=(12.0,), pillar_mm=2.0, pillar_height_mm=(6.0,),
        noise=0.02, bias=0.4, yaw_deg=0.0),
    "thin-pillar-under-2-voxels": Case(
        seed=505, spacing_mm=(0.8, 1.2, 1.1), inclusion_mm=(10.0, 9.0), pillar_mm=1.6,
        pillar_height_mm=(5.0, 9.0), silicone_brighter=True, base_up=True, noise=0.05, bias=0.2),
    "tilted-6deg-two-inclusions-bright-base-up": Case(
        seed=506, spacing_mm=(0.9, 0.7, 0.7), inclusion_mm=(9.0, 13.0), pillar_mm=2.4,
        pillar_height_mm=(11.0, 4.0), base_up=True, silicone_brighter=True, noise=0.05, bias=0.3,
        tilt_deg=6.0, tilt_azimuth_deg=115.0),
    "tilted-10deg-anisotropic-dark-noisy": Case(
        seed=507, spacing_mm=(1.1, 0.6, 0.8), inclusion_mm=(7.0, 12.0, 15.0), pillar_mm=3.5,
        pillar_height_mm=(2.0, 13.0, 7.0), noise=0.09, bias=0.2, tilt_deg=10.0, tilt_azimuth_deg=250.0),
}


@pytest.fixture(scope="module")
def results() -> dict:
    """Each case generated and segmented once for the module."""
    out = {}
    for name, case in CASES.items():
        vol = generate(case)
        out[name] = (vol, segment(vol.image, vol.spacing_mm, where=name))
    return out


# Rows that miss the acceptance today, with why (strict: a row that starts passing must leave this list).
SHORT_OF_ACCEPTANCE: dict[str, str] = {}

# Rows whose pillar is not found (one warning naming the inclusion), with why.
PILLAR_NOT_FOUND: dict[str, str] = {}


@pytest.mark.parametrize("name",
                         [pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=SHORT_OF_ACCEPTANCE[n]))
                                  if n in SHORT_OF_ACCEPTANCE else n for n in sorted(CASES)])
def test_dice_meets_acceptance(results, name):
    vol, seg = results[name]
    assert scores(seg.labels, vol.truth)["insert"] >= MIN_DICE["insert"], name
    wide = pillar_voxels_wide(vol.case) >= MIN_PILLAR_VOXELS
    for row in inclusion_scores(seg.labels, vol):
        assert row["dice_inclusion"] >= MIN_DICE["inclusion"], (name, row)
        if wide:
            assert row["dice_pillar"] >= MIN_DICE["pillar"], (name, row)


@pytest.mark.parametrize("name", sorted(CASES))
def test_contrast_found_and_no_warnings(results, name):
    vol, seg = results[name]
    assert seg.silicone_brighter == vol.case.silicone_brighter
    if name in PILLAR_NOT_FOUND:
        assert (len(seg.warnings) == 1
                and "no pillar found under the inclusion" in seg.warnings[0]), PILLAR_NOT_FOUND[name]
    else:
        assert seg.warnings == []


@pytest.mark.parametrize("name", list(CASES))
def test_base_surface_is_found_within_a_quarter_slice(results, name):
    """The base's surface found under the posts (`Segmentation.base_surface`): its normal along the insert
    axis (tilted or not), pointing into the base, and the plane within a quarter of a slice of the true
    one."""
    vol, seg = results[name]
    base = seg.base_surface
    assert base is not None and float(np.dot(base.normal, vol.axis_mm)) < -(1.0 - 1e-3)
    assert abs(base_error_mm(base, vol)) < 0.25 * vol.spacing_mm[0]


# Posts whose measures miss those bounds today, with why (strict).
POST_OFF: dict[str, str] = {
    "coarse-1.2mm-4mm-pillar-1mm-tall-16mm-bright": "a 4 mm post 1 mm tall in 1.2 mm slices is measured 3.46 "
                                                    "mm wide: no slab of its own, its radius fitted to the "
                                                    "silicone the blur spreads into the ball's and the "
                                                    "base's, the base's surface found 0.16 mm short of it "
                                                    "(3.34 mm before its slabs were centred on the slices, "
                                                    "3.17 mm before the ball's fit left its cap out, 3.56 mm "
                                                    "while the fit started at the plane under the ball, "
                                                    "whose excess made up for that; its Dice meets the "
                                                    "target: its truth is one slice, 8 voxels)",
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=POST_OFF[n]))
                                  if n in POST_OFF else n for n in CASES])
def test_each_post_is_found_on_its_axis_as_wide_and_as_tall(results, name):
    """The posts drawn (`Segmentation.posts`): one under each inclusion, standing along the insert axis
    towards it, the foot within half an in-plane voxel of the true axis, the diameter within a quarter of
    one (where the post is at least 2 voxels wide; the thinner ones within half) and the height within
    half a slice."""
    vol, seg = results[name]
    voxel = max(vol.spacing_mm[1:])
    assert len(seg.posts) == len(vol.case.inclusion_mm)
    assert all(float(np.dot(post.direction, vol.axis_mm)) > 0.99 for post in seg.posts)
    wide = pillar_voxels_wide(vol.case) >= MIN_PILLAR_VOXELS
    for err in post_errors(seg.posts, vol):
        assert err["post_offset_mm"] is not None and err["post_offset_mm"] < 0.5 * voxel
        assert abs(err["post_diameter_error_mm"]) < (0.25 if wide else 0.5) * voxel
        assert abs(err["post_height_error_mm"]) < 0.5 * vol.spacing_mm[0]


def test_a_thin_post_beside_the_skin_is_found():
    """Family seed 35: a 1.7 mm post (1.5 voxels of 1.11 mm) 14 mm tall under a 6.2 mm inclusion, its axis
    6.4 mm from the skin on the insert's wall, which (with its blur) takes part of the ring around the
    post, 4.5-7 mm out. The ring's level is the hydrogel's, not pulled up by the skin (a plain median was,
    by enough over the core to cancel the post's whole cross-section: no post found, one warning)."""
    from mri_family import draw_case

    vol = generate(draw_case(35))
    seg = segment(vol.image, vol.spacing_mm, where="seed 35")
    voxel = max(vol.spacing_mm[1:])
    assert seg.warnings == [] and len(seg.posts) == 2
    for err in post_errors(seg.posts, vol):
        assert err["post_offset_mm"] < 0.5 * voxel and abs(err["post_diameter_error_mm"]) < 0.5 * voxel


def test_a_small_sphere_read_elongated_is_told_not_lost_silently():
    """Family seed 1016 tilted (`mri_family.py --tilted`, 6.5 degrees): its 6.3 mm sphere at 1.11 mm voxels
    and noise 0.085 opens, under the smaller ball, to 45 voxels spread 1.68 times more along one axis than
    across (over MAX_ELONGATION), so it is not taken for an inclusion; it lies in the filling and off the
    other inclusion's axis, and one warning names the voxel of its centre (upright it is found, 0.941). The
    other
    inclusion is labelled."""
    from mri_family import draw_case, tilted

    vol = generate(tilted(draw_case(1016)))
    seg = segment(vol.image, vol.spacing_mm, where="seed 1016 tilted")
    (warning,) = seg.warnings
    assert "is not round: not labelled an inclusion" in warning
    named = np.array(json.loads(warning.split("near voxel ")[1].split(" holds")[0]))
    small = int(np.argmin(vol.case.inclusion_mm))
    assert np.linalg.norm((named - vol.centres_index[small]) * vol.spacing_mm) < 2.0 * max(vol.spacing_mm)
    assert [round(r["dice_inclusion"], 2) > 0.93 for r in inclusion_scores(seg.labels, vol)] == [
        k != small for k in range(len(vol.case.inclusion_mm))]


def test_a_bases_silicone_without_posts_is_not_told_as_a_small_inclusion():
    """Family seed 1091 of `mri_family.py --near-skin --floating` (ramp): no post, the sphere 0.54 mm under
    the skin. Under the shell set aside at the outer surface, the base's silicone opens under the smaller ball
    to a flat piece of 1971 voxels, elongated and off the sphere's axis; with no post no base surface is found
    to set it aside, and it was told as a small inclusion that is not round. A piece whose centre lies within
    the thickest skin (and a voxel) of the insert's outer surface is the skin's or the base's: the sphere's
    "no
    pillar" warning alone is left."""
    vol = generate(Case(seed=1091, spacing_mm=(1.11, 1.19, 1.19), inclusion_mm=(11.4,), pillar_mm=0.0,
                        pillar_height_mm=(10.6,), silicone_brighter=True, noise=0.044, bias=0.33,
                        skin_gap_mm=0.54))
    seg = segment(vol.image, vol.spacing_mm, where="seed 1091 without posts")
    (warning,) = seg.warnings
    assert warning.startswith("pillar not connected: no pillar found under the inclusion")
    assert inclusion_scores(seg.labels, vol)[0]["dice_inclusion"] >= 0.93


def test_inclusion_thinner_than_the_ball_voxel_for_voxel_is_found():
    """A 6 mm inclusion at 1 mm voxels: the ball that removes a 4.5 mm pillar does not fit its voxels."""
    from scipy import ndimage

    vol = generate(Case(seed=604, spacing_mm=(0.8, 1.01, 1.01), inclusion_mm=(6.0, 12.0), pillar_mm=2.5,
                        pillar_height_mm=(12.6, 6.0), base_up=True, noise=0.06, bias=0.4))
    seg = segment(vol.image, vol.spacing_mm, where="small")
    assert ndimage.label(seg.labels == 3)[1] == 2
    assert seg.warnings == []
    assert all(row["dice_inclusion"] >= 0.9 for row in inclusion_scores(seg.labels, vol))


def test_a_noisy_small_sphere_at_coarse_voxels_is_found():
    """A 6.3 mm sphere 1 mm under the skin at 1.11 mm voxels and noise 0.085 (seed 1016 of ``mri_family.py
    --near-skin``): opened by the smaller ball, its body holds 0.92 of the main ball's volume. Round and off
    the other inclusion's axis, it is an inclusion (morphology._off_axis); taken for a piece of a post, it
    was missed with no warning."""
    vol = generate(Case(seed=1016, spacing_mm=(1.12, 1.11, 1.11), inclusion_mm=(12.3, 6.3), pillar_mm=3.53,
                        pillar_height_mm=(9.2, 11.8), noise=0.085, bias=0.116, partial_volume="box",
                        skin_gap_mm=1.02))
    seg = segment(vol.image, vol.spacing_mm, where="small noisy sphere")
    assert all(row["dice_inclusion"] >= MIN_DICE["inclusion"] for row in inclusion_scores(seg.labels, vol))


def test_a_small_sphere_opened_to_a_few_voxels_is_round():
    """A 6 mm sphere at 1.08-1.19 mm voxels (``mri_family.py --small-coarse`` seed 49233), alone on a 3.71 mm
    post, opens to 36 voxels, 3 x 3 x 4, whose centres spread 1.51 times more along one axis than across
    (over MAX_ELONGATION, 1.5); counted as boxes, 1.47 (morphology._round). Read as elongated, no inclusion
    was found (one warning)."""
    vol = generate(Case(seed=49233, spacing_mm=(1.08, 1.18, 1.19), inclusion_mm=(6.0,), pillar_mm=3.71,
                        pillar_height_mm=(7.8,), base_up=True, noise=0.082, bias=0.309, partial_volume="box"))
    seg = segment(vol.image, vol.spacing_mm, where="few voxels")
    assert seg.warnings == []
    (row,) = inclusion_scores(seg.labels, vol)
    assert row["dice_inclusion"] >= MIN_DICE["inclusion"] and row["dice_pillar"] >= MIN_DICE["pillar"]


SMALL_ON_THICK = {
    # a 6.9 mm sphere on a 3.77 mm post at 1.13 mm voxels (mri_family.py --small-coarse, seed 4909): the
    # post's
    # blur beside it misfit the ball (1.45), whose image surface scored 0.895
    "6.9mm-on-3.8mm-post": Case(seed=4909, spacing_mm=(1.13, 1.09, 1.12), inclusion_mm=(6.9, 10.1, 11.8),
                                pillar_mm=3.77, pillar_height_mm=(13.0, 8.3, 7.4), noise=0.07, bias=0.13,
                                partial_volume="box"),
    # a 6.7 mm sphere on a 2.19 mm post at 1.17 mm voxels, base up, bright silicone (seed 4907): 0.922
    "6.7mm-on-2.2mm-post": Case(seed=4907, spacing_mm=(1.09, 1.17, 1.07), inclusion_mm=(6.7, 7.7),
                                pillar_mm=2.19, pillar_height_mm=(10.4, 8.7), base_up=True,
                                silicone_brighter=True, noise=0.077, bias=0.336, partial_volume="box"),
}


@pytest.mark.parametrize("name", sorted(SMALL_ON_THICK))
def test_a_small_sphere_on_a_thick_post_is_drawn_as_its_ball(name):
    """A sphere of 6-7 mm at coarse voxels on a post of more than a third its width: the voxels within a voxel
    of the drawn post (outside the inclusion's body) hold the post's blur, which is no part of the ball, and
    are left out of its fit (morphology.BLUR_VOXELS); the ball then fits to the noise and is drawn."""
    vol = generate(SMALL_ON_THICK[name])
    seg = segment(vol.image, vol.spacing_mm, where=name)
    assert seg.warnings == []
    assert all(row["shape"] == "ball" for row in seg.inclusion_shapes)
    assert all(row["dice_inclusion"] >= 0.96 for row in inclusion_scores(seg.labels, vol))


POST_PIECES = {
    # a 3.84 mm post at 1.14 mm voxels, noise 0.075: a round piece of it under its 13.9 mm inclusion holds
    # more
    # than half the main ball's volume; every such piece taken drew it as a third inclusion (pillar 0.92)
    20: "box",
    # a 2.48 mm post's foot on the base, under a 15.3 mm inclusion: 1.01 of the ball's volume and, its voxels
    # counted as boxes, round; taken without the axis test, a third inclusion (pillar 1.00 -> 0.64)
    2054: "ramp",
}


@pytest.mark.parametrize("seed", sorted(POST_PIECES))
def test_a_piece_of_a_post_is_not_taken_for_an_inclusion(seed):
    """Family seeds 20 and 2054: opened by the smaller ball, a round piece of a post (or of its foot) lies on
    its inclusion's axis, so it is a piece of that post, not an inclusion (morphology._off_axis)."""
    from dataclasses import replace

    from scipy import ndimage

    vol = generate(replace(draw_case(seed), partial_volume=POST_PIECES[seed]))
    seg = segment(vol.image, vol.spacing_mm, where=f"seed {seed}")
    rows = inclusion_scores(seg.labels, vol)
    assert seg.warnings == [] and len(seg.posts) == len(rows) == ndimage.label(seg.labels == INCLUSION)[1]
    assert all(row["dice_inclusion"] >= MIN_DICE["inclusion"] and row["dice_pillar"] >= MIN_DICE["pillar"]
               for row in rows)


@pytest.mark.parametrize("brighter", [False, True])
@pytest.mark.parametrize("spacing", [(1.15, 1.15, 1.15), (1.2, 1.0, 0.8)])
def test_small_inclusions_at_coarse_voxels_are_not_cut_small(spacing, brighter):
    """No noise, voxels 0.8-1.2 mm: inclusions of 6, 8 and 12 mm each meet Dice 0.95.

    Blurred, a small sphere reads below half its contrast at its surface; the half-way level cut the
    6 and 8 mm ones up to 0.17 mm short in radius (Dice down to 0.93)."""
    vol = generate(Case(seed=630, spacing_mm=spacing, inclusion_mm=(6.0, 8.0, 12.0), pillar_mm=2.5,
                        pillar_height_mm=(12.0, 6.0, 3.0), silicone_brighter=brighter, noise=0.0, bias=0.1))
    seg = segment(vol.image, vol.spacing_mm, where="clean")
    assert seg.warnings == []
    assert all(row["dice_inclusion"] >= 0.95 for row in inclusion_scores(seg.labels, vol))


@pytest.mark.parametrize("seed", [507, 521])
def test_short_pillar_at_thick_slices_in_a_clean_scan(seed):
    """No noise, 1.16 mm slices: pillars 1.5 mm and 5 mm tall are each found and end at the base.

    The trace's slabs are one slice each here; slabs bounded at voxel centres mixed two slices and read
    the level next to the base a slice off (or saw no pillar at all)."""
    vol = generate(Case(seed=seed, spacing_mm=(1.16, 0.83, 0.41), inclusion_mm=(8.2, 11.0, 12.9),
                        pillar_mm=1.94, pillar_height_mm=(5.1, 1.5, 5.3), base_up=True,
                        silicone_brighter=True, noise=0.0, bias=0.3))
    seg = segment(vol.image, vol.spacing_mm, where="clean")
    assert seg.warnings == []
    assert all(row["dice_pillar"] >= MIN_DICE["pillar"] for row in inclusion_scores(seg.labels, vol))


def test_short_pillar_is_not_widened_by_the_blurred_cap_of_its_inclusion():
    """No noise, 0.9 mm slices: a 2 mm pillar 1.6 mm tall under a 7 mm inclusion meets pillar Dice 0.80.

    Two slabs lie between the inclusion and the base; the blurred cap of the small sphere reaches past
    the first into the second, whose excess silicone read 11 % above the pillar's cross-section (Dice
    0.77). The inclusion's fitted blurred ball is taken out of the slabs first."""
    vol = generate(Case(seed=730, spacing_mm=(0.9, 0.5, 0.5), inclusion_mm=(7.0, 9.0), pillar_mm=2.0,
                        pillar_height_mm=(1.6, 2.0), noise=0.0, bias=0.1, yaw_deg=20.0))
    seg = segment(vol.image, vol.spacing_mm, where="cap")
    assert seg.warnings == []
    assert all(row["dice_pillar"] >= MIN_DICE["pillar"] for row in inclusion_scores(seg.labels, vol))


def test_base_surface_is_not_placed_deep_by_a_noisy_base_level():
    """0.48 mm slices, noise 0.08: a 1.1 mm pillar does not take a slice of the base (pillar Dice 0.80).

    The base's level was the highest of its slabs' ring medians, which noise biases upwards; the
    half-way crossing then lay 0.05-0.09 mm too deep, past the plane of a slice 0.04 mm inside the base,
    and that slice was labelled pillar under all three inclusions (Dice 0.78 on the shortest). The
    level is now the mean of the base's slabs past the one that straddles its surface."""
    vol = generate(Case(seed=16, spacing_mm=(0.48, 1.14, 0.76), inclusion_mm=(14.1, 9.9, 8.4), pillar_mm=3.61,
                        pillar_height_mm=(4.4, 6.0, 1.1), base_up=True, noise=0.082, bias=0.275))
    seg = segment(vol.image, vol.spacing_mm, where="base")
    assert seg.warnings == []
    assert all(row["dice_pillar"] >= MIN_DICE["pillar"] for row in inclusion_scores(seg.labels, vol))


@pytest.mark.parametrize("seed", [760, 761])
def test_post_one_slice_tall_under_large_inclusions_leaves_them_balls(seed):
    """1.03 mm slices: 3.4 mm posts 1.1 and 1.3 mm tall under a 15.8 and a 15 mm inclusion (pillar Dice 0.80).

    The base lies within the blur of each ball's cap; fitted with it, the ball's misfit rose over the noise
    (1.8-2.0 times it), the inclusion kept the image's surface, which the blur carried over the post
    (pillar Dice 0.54-0.62 on three of the four). The base's silicone, past its surface found under the
    posts, is left out of the ball's fit (misfit 0.9).

    With the bias field refitted clear of the tissues' boundaries the noise read around the 15 mm ball of
    seed 760 was no longer widened by the field's bend, and its misfit rose to 1.251 (image surface, pillar
    Dice 0.77); the post's own blurred silicone, read in the ball's cap and fitted with it, was the rest:
    left out (the core from a voxel inside the body's end, `ball.CAP_SHUT_VOXELS`), 1.226."""
    vol = generate(Case(seed=seed, spacing_mm=(1.03, 0.73, 0.73), inclusion_mm=(15.8, 15.0), pillar_mm=3.36,
                        pillar_height_mm=(1.1, 1.3), noise=0.035, bias=0.3))
    seg = segment(vol.image, vol.spacing_mm, where="short posts")
    assert seg.warnings == [] and [row["shape"] for row in seg.inclusion_shapes] == ["ball", "ball"]
    assert all(row["dice_pillar"] >= MIN_DICE["pillar"] for row in inclusion_scores(seg.labels, vol))


BALLS_A_SLICE_OFF_THE_BASE = {
    # a 9.5 mm sphere on a 2.6 mm post 1.1 mm tall at 0.95 mm slices, bright silicone: misfit 2.2, the image's
    # surface took the base's blurred slice around the post (inclusion 0.978, pillar 0.50)
    "9.5mm-1.1mm-off": Case(seed=904, spacing_mm=(0.95, 1.15, 1.15), inclusion_mm=(9.5,), pillar_mm=2.6,
                            pillar_height_mm=(1.1,), silicone_brighter=True, noise=0.03,
                            partial_volume="box"),
    # a 14 mm sphere on a 2.5 mm post 1.2 mm tall at 1.0 mm slices, dark silicone: misfit 1.65 (inclusion
    # 0.984)
    "14mm-1.2mm-off": Case(seed=906, spacing_mm=(1.0, 1.2, 1.1), inclusion_mm=(14.0,), pillar_mm=2.5,
                           pillar_height_mm=(1.2,), noise=0.04, partial_volume="box"),
}


@pytest.mark.parametrize("name", sorted(BALLS_A_SLICE_OFF_THE_BASE))
def test_a_ball_a_slice_off_the_base_leaves_the_bases_blur_out_of_its_fit(name):
    """A ball on a post about a slice tall: the slice between them holds the base's blurred and partial-volume
    silicone on the filling's side of its surface, no part of the ball; fitted with it, the ball misfit over
    BALL_MISFIT and the image's surface, drawn instead, took that slice around the post. The voxels within
    a voxel of the base's surface are left out of the fit (morphology.BLUR_VOXELS, as around a post)."""
    vol = generate(BALLS_A_SLICE_OFF_THE_BASE[name])
    seg = segment(vol.image, vol.spacing_mm, where=name)
    assert seg.warnings == [] and [row["shape"] for row in seg.inclusion_shapes] == ["ball"]
    assert inclusion_scores(seg.labels, vol)[0]["dice_inclusion"] >= 0.99


LONE_SHORT_POSTS = [(voxel, post, tall) for voxel in (0.6, 0.95) for post in (2.0, 3.0)
                    for tall in (1.2, 2.0)]


def test_a_lone_short_posts_diameter_holds_no_excess_from_the_balls_curve():
    """No noise, bias 0.1, isotropic voxels of 0.6 and 0.95 mm: posts 2 and 3 mm wide, 1.2 and 2 mm tall,
    each under the scan's only inclusion (8 mm, where the ball curves most), are drawn within 0.05 mm of
    their diameter on average over the 8 scans, and each within 0.3 of a voxel.

    Such a post's radius is fitted to all its silicone (`_post_radius`); from the plane through the
    ball's lowest point, the silicone between that plane and the ball's surface (pi r^4 / (4 R)) widened
    these posts by 0.135 mm on average (up to 0.37 mm, 0.38 of a voxel); the post now starts at the ball's
    surface.

    With the bias field refitted clear of the tissues' boundaries they came out -0.052 mm on average (7 of
    8 thin; -0.17 mm for the 3 mm post 1.2 mm tall at 0.95 mm): the post's blurred silicone in the ball's
    cap drew the fitted ball 0.1 mm towards it, and the post's start with it. The ball's fit now leaves
    the core out from a voxel inside the body's end (`ball.CAP_SHUT_VOXELS`, chosen on 24 other lone
    short posts, seeds 900-923): -0.020 mm."""
    errors = []
    for k, (voxel, post, tall) in enumerate(LONE_SHORT_POSTS):
        vol = generate(Case(seed=640 + k, spacing_mm=(voxel,) * 3, inclusion_mm=(8.0,), pillar_mm=post,
                            pillar_height_mm=(tall,), noise=0.0, bias=0.1, partial_volume="box"))
        seg = segment(vol.image, vol.spacing_mm, where="lone short post")
        assert seg.warnings == []
        errors.append(post_errors(seg.posts, vol)[0]["post_diameter_error_mm"])
    voxels = np.array([voxel for voxel, _post, _tall in LONE_SHORT_POSTS])
    assert abs(np.mean(errors)) < 0.05 and np.abs(np.array(errors) / voxels).max() < 0.3


ALL_SHORT_POSTS = [(post, talls) for post in (2.0, 3.0) for talls in ((1.2, 2.0), (1.5, 2.5, 1.0))]


def test_posts_all_short_are_drawn_from_their_fits_not_their_own_slabs():
    """No noise, bias 0.1, 0.95 mm isotropic voxels: two or three inclusions (8-10 mm), each on a post 2 or
    3 mm wide and 1-2.5 mm tall, none measured over `section.MIN_OWN_SLABS` slabs: every post is drawn
    within 0.05 mm of its diameter.

    The posts of such a scan took the median cross-section of their own few slabs, pooled; the blur
    carries much of a post a slab or two tall into its inclusion's and the base's slabs, and these came
    out 0.04-0.11 mm thin (so did the posts of all six such volumes of the family's seeds 0-6099 and
    7000-7149 under the box, by 0.01-0.23 mm). They now take the median of their radii fitted to all their
    silicone (`_post_radius`): -0.03 to
    +0.03 mm here. At 0.6 mm voxels the slabs read these posts within 0.02 mm and the fits within 0.06."""
    for k, (post, talls) in enumerate(ALL_SHORT_POSTS):
        vol = generate(Case(seed=804 + k, spacing_mm=(0.95,) * 3, inclusion_mm=(8.0, 10.0, 9.0)[:len(talls)],
                            pillar_mm=post, pillar_height_mm=talls, noise=0.0, bias=0.1,
                            partial_volume="box"))
        seg = segment(vol.image, vol.spacing_mm, where="short posts")
        assert seg.warnings == []
        errors = [row["post_diameter_error_mm"] for row in post_errors(seg.posts, vol)]
        assert len(errors) == len(talls) and np.abs(errors).max() < 0.05, (post, talls, errors)


def test_a_short_posts_radius_holds_in_a_tilted_noisy_scan():
    """A 3.5 mm post 1.6 mm tall under an 11 mm ball, 0.9 x 0.6 x 0.6 mm voxels, noise 0.07, the insert tilted
    5 degrees off the slices (four azimuths): each post drawn within a quarter of an in-plane voxel of its
    diameter, as the same scans untilted are.

    The fit of a short post's radius (`_post_radius`) read each core voxel's excess over its slab's ring
    level. In a tilted scan a slab's voxels spread over its depth, and about the base's surface, where the
    level climbs from the hydrogel's to the silicone's within a slab, that one level was the wrong background
    for most of them: these posts came out -0.61, -0.02, -0.55 and -0.48 mm (seed 36 of the family's
    `--tilted`, a 3.9 mm post 1.4 mm tall tilted 5 degrees: -0.34 +- 0.12 mm over eight noise draws, +0.08
    untilted). Each voxel's background is now the ring's level at its own depth, read over half-slabs and
    interpolated: where the slices are normal to the axis every voxel lies at a half-slab's depth and reads
    its slab's level as
    before."""
    for seed in range(600, 604):
        case = Case(seed=seed, spacing_mm=(0.9, 0.6, 0.6), inclusion_mm=(11.0,), pillar_mm=3.5,
                    pillar_height_mm=(1.6,), noise=0.07, bias=0.15, silicone_brighter=True, tilt_deg=5.0,
                    tilt_azimuth_deg=40.0 + 50 * (seed - 600))
        vol = generate(case)
        seg = segment(vol.image, vol.spacing_mm, where="tilted short post")
        (error,) = post_errors(seg.posts, vol)
        assert abs(error["post_diameter_error_mm"]) < 0.25 * 0.6, (seed, error)
        assert abs(error["post_height_error_mm"]) < 0.5 * 0.9, (seed, error)


def test_a_posts_base_is_found_as_closely_in_a_tilted_noisy_scan():
    """A 2.9 mm post 4.5 mm tall under a 12.5 mm ball, 0.93 x 0.92 x 0.95 mm voxels, noise 0.09, the insert
    tilted 3 degrees off the slices (six azimuths): each post's height within a tenth of a slice of the truth,
    as the same scans upright are (-0.083 to +0.005 mm).

    The slabs along a tilted axis were as thick as a voxel's extent along it, a little more than the planes of
    voxel centres are apart along it, so a slab caught one plane and now and then a part of the next; a ring
    level read over two planes' voxels, the one mostly hydrogel and the other mostly the base's silicone, is
    moved by the noise towards the lesser part, and the base's profile was fitted to such levels: heights
    -0.215 to +0.047 mm here. Each slab now holds one plane where the tilt is small enough for the planes to
    stay apart across the ring: -0.030 to +0.042 mm."""
    for seed in range(610, 616):
        case = Case(seed=seed, spacing_mm=(0.93, 0.92, 0.95), inclusion_mm=(12.5,), pillar_mm=2.9,
                    pillar_height_mm=(4.5,), noise=0.09, bias=0.2, tilt_deg=3.0,
                    tilt_azimuth_deg=20.0 + 60 * (seed - 610), partial_volume="box")
        vol = generate(case)
        seg = segment(vol.image, vol.spacing_mm, where="tilted post")
        (error,) = post_errors(seg.posts, vol)
        assert abs(error["post_height_error_mm"]) < 0.1 * 0.93, (seed, error)


def test_a_tilted_volume_keeps_its_tissues_and_tells_where_its_axis_and_feet_lie():
    """`Case(tilt_deg=...)`: the insert tilted off array axis 0 holds each tissue's volume (the octagonal
    prism's, the posts' up to their spheres' surfaces, the spheres'; within 1 % at 0.4 mm voxels, 3 % for the
    posts, of some 65 mm^3 of 0.064 mm^3 voxels), each inclusion's centre and foot lie on the line along
    `Volume.axis_mm` through them, the centre in the inclusion and the foot at the base's surface (pillar
    voxels just above it,
    none below), and no slice is left undecided."""
    import dataclasses

    upright = Case(seed=7, spacing_mm=(0.4, 0.4, 0.4), inclusion_mm=(10.0, 8.0), pillar_mm=3.0,
                   pillar_height_mm=(6.0, 3.0), width_mm=40.0, partial_volume="box")
    r = 0.5 * upright.pillar_mm

    def under_sphere(big: float) -> float:
        """A post's volume between its sphere's lowest plane and its surface (the sphere of radius
        ``big``)."""
        return math.pi * r * r * big - 2.0 * math.pi / 3.0 * (big ** 3 - (big * big - r * r) ** 1.5)

    posts = sum(math.pi * r * r * h + under_sphere(0.5 * d) for h, d in zip(upright.pillar_height_mm,
                                                                             upright.inclusion_mm))
    spheres = sum(math.pi / 6.0 * d ** 3 for d in upright.inclusion_mm)
    side = upright.width_mm * math.tan(math.pi / 8)
    for base_up in (False, True):
        vol = generate(dataclasses.replace(upright, base_up=base_up, tilt_deg=7.0, tilt_azimuth_deg=33.0),
                       image=False)
        voxel = float(np.prod(vol.spacing_mm))
        prism = 2.0 * (1.0 + math.sqrt(2.0)) * side * side * vol.height_mm
        for label, volume, rel in ((INSERT, prism - posts - spheres, 0.01), (PILLAR, posts, 0.03),
                                   (INCLUSION, spheres, 0.01)):
            assert (vol.truth == label).sum() * voxel == pytest.approx(volume, rel=rel), label
        tilt = math.degrees(math.acos(abs(float(vol.axis_mm[0]))))
        assert tilt == pytest.approx(7.0) and np.linalg.norm(vol.axis_mm) == pytest.approx(1.0)
        spacing = vol.spacing_mm
        for centre, foot, height, diameter in zip(vol.centres_index, vol.feet_index, upright.pillar_height_mm,
                                                  upright.inclusion_mm):
            along = (centre - foot) * spacing
            assert along == pytest.approx((height + 0.5 * diameter) * vol.axis_mm)
            assert vol.truth[tuple(np.round(centre).astype(int))] == INCLUSION
            grid = np.stack(np.nonzero(vol.truth == PILLAR), axis=1) * spacing
            near = np.linalg.norm(grid - foot * spacing, axis=1) < 3.0
            depth = (grid[near] - foot * spacing) @ vol.axis_mm
            assert depth.min() >= 0.0 and depth.min() < 0.5
        assert not vol.undecided_slices().any()


KNOWN_DIAMETER_POSTS = [(pv, voxel, post) for pv in ("box", "ramp") for voxel in (0.8, 1.1)
                        for post in (2.0, 3.0)]


def test_a_given_diameter_draws_noisy_lone_short_posts_that_wide_where_the_scan_finds_them():
    """Noise 0.1 (the family's most), bias 0.3: lone posts 2 and 3 mm wide and 1.5 mm tall under a 9 mm
    inclusion, at 0.8 and 1.1 mm voxels, box and ramp partial volume. Such a post's radius is fitted to the
    few voxels of its own silicone, and the noise carries it: drawn as measured, 2.02-3.73 mm wide, pillar
    Dice down to 0.62. Given the diameter as cast (`SegmentParams.pillar_diameter_mm`, `less mri-label
    --pillar-diameter-mm`), each post is drawn that wide, on the line and to the base the scan gives, and
    keeps the diameter the scan measured; each meets the pillar target. A volume without posts given a
    diameter still gets none."""
    from lesscli.mri.segment import SegmentParams

    blind_dice, given_dice = [], []
    for k, (pv, voxel, post) in enumerate(KNOWN_DIAMETER_POSTS):
        vol = generate(Case(seed=660 + k, spacing_mm=(voxel,) * 3, inclusion_mm=(9.0,), pillar_mm=post,
                            pillar_height_mm=(1.5,), noise=0.1, bias=0.3, partial_volume=pv))
        blind = segment(vol.image, vol.spacing_mm, where="lone short post")
        given = segment(vol.image, vol.spacing_mm, SegmentParams(pillar_diameter_mm=post),
                        where="lone short post")
        assert blind.warnings == given.warnings == [] and len(blind.posts) == len(given.posts) == 1
        (drawn,), (measured,) = given.posts, blind.posts
        assert drawn.radius_mm == 0.5 * post and drawn.measured_radius_mm == measured.radius_mm
        assert measured.measured_radius_mm is None
        np.testing.assert_allclose(drawn.foot_mm, measured.foot_mm)
        assert drawn.height_mm == measured.height_mm
        blind_dice.append(inclusion_scores(blind.labels, vol)[0]["dice_pillar"])
        given_dice.append(inclusion_scores(given.labels, vol)[0]["dice_pillar"])
    assert min(given_dice) >= MIN_DICE["pillar"] and np.mean(given_dice) > np.mean(blind_dice)
    floating = generate(Case(seed=506, spacing_mm=(0.9, 0.8, 0.8), inclusion_mm=(9.0, 12.0), pillar_mm=0.0,
                             pillar_height_mm=(4.0, 8.0), noise=0.05, bias=0.2))
    seg = segment(floating.image, floating.spacing_mm, SegmentParams(pillar_diameter_mm=3.0),
                  where="floating")
    assert not (seg.labels == PILLAR).any() and seg.posts == [] and len(seg.warnings) == 2


SKIN_GAP_CASES = [(spacing, gap, up) for spacing in ((1.2, 1.2, 1.2), (1.15, 0.8, 0.8)) for gap in (0.8, 1.2)
                  for up in (False, True)]


def test_a_sphere_just_under_the_skin_keeps_its_post_on_the_base_side():
    """A 12 mm sphere 0.8 or 1.2 mm under the skin (the drawn family keeps its spheres 2 mm or more from
    it; the catalogue's inserts hold theirs 1.5 mm under it) on a 3 mm post 10 mm tall, at voxels of
    1.15-1.2 mm along the axis, base down and up. The short gap to the skin holds no voxel, or one that the
    skin's and the sphere's blur fill, and it was taken for the side of the post: in 7 of these 8 scans
    the post under the sphere was lost (Dice 0, with a warning in 3). A significant post at least
    `section.CLEAR_POST_RADIUS_MM` wide on the other side now decides."""
    for k, (spacing, gap, up) in enumerate(SKIN_GAP_CASES):
        vol = generate(Case(seed=680 + k, spacing_mm=spacing, inclusion_mm=(12.0,), pillar_mm=3.0,
                            pillar_height_mm=(10.0,), skin_gap_mm=gap, base_up=up, noise=0.05, bias=0.25))
        seg = segment(vol.image, vol.spacing_mm, where=f"sphere {gap} mm under the skin")
        assert seg.warnings == []
        assert inclusion_scores(seg.labels, vol)[0]["dice_pillar"] >= MIN_DICE["pillar"], (spacing, gap, up)
        assert scores(seg.labels, vol.truth)["insert"] >= MIN_DICE["insert"]


THIN_SKIN_CASES = [(spacing, gap, up) for spacing in ((0.8, 0.6, 0.6), (1.15, 0.7, 0.7)) for gap in (0.8, 1.6)
                   for up in (False, True)]


def test_a_thin_post_under_a_sphere_just_under_the_skin_is_found():
    """A 1.5 mm post (the thinnest cast; 2.1-2.5 voxels wide) 9-10 mm tall under a 12 mm sphere 0.8 or 1.6 mm
    under the skin, base down and up. Its trace (about 2 mm^2 over 5-15 slabs, significant) lies under the
    disc 2 mm across that outweighed a short gap to the skin before, and a gap of a slab or two to the skin
    leaves a trace too short to test against the noise, which the skin's and the sphere's blur fill as
    well as a post would: 10 of 12 such scans at 0.8 and 1.2 mm lost the post. A significant post of at
    least CLEAR_POST_RADIUS_MM now decides against a short gap or a trace under 3 slabs on the other side."""
    for k, (spacing, gap, up) in enumerate(THIN_SKIN_CASES):
        vol = generate(Case(seed=740 + k, spacing_mm=spacing, inclusion_mm=(12.0,), pillar_mm=1.5,
                            pillar_height_mm=(10.0 - gap + 0.8,), skin_gap_mm=gap, base_up=up, noise=0.05,
                            bias=0.25))
        seg = segment(vol.image, vol.spacing_mm, where=f"thin post, sphere {gap} mm under the skin")
        assert seg.warnings == [], (spacing, gap, up)
        assert inclusion_scores(seg.labels, vol)[0]["dice_pillar"] >= MIN_DICE["pillar"], (spacing, gap, up)


CLEAR_RING_POSTS = [(slices, tall, inclusion) for slices in (1.1, 1.2) for tall in (1.3, 1.8)
                    for inclusion in (10.0, 14.0)]


def test_a_short_posts_base_surface_is_read_clear_of_its_ball(monkeypatch):
    """Noise 0.03, bias 0.2, slices 1.1 and 1.2 mm: a 2.5 mm post 1.3 or 1.8 mm tall under the scan's only
    inclusion (10 or 14 mm), both contrasts. The post's own trace holds too few slabs for the base's profile
    fit; its base surface, read in an annulus clear of the ball instead (`_clear_end`), lies nearer the truth
    than the half-way crossing of the trace's ring levels that stood before (mean absolute error over the 8
    scans), and is less biased.

    (On 16 more such scans without noise: mean error -0.053 -> -0.007 mm, mean absolute 0.081 -> 0.058 mm.)"""
    from lesscli.mri import pillar

    volumes = [generate(Case(seed=720 + k, spacing_mm=(slices, 0.9, 0.9), inclusion_mm=(inclusion,),
                             pillar_mm=2.5, pillar_height_mm=(tall,), silicone_brighter=bool(k % 2),
                             noise=0.03, bias=0.2, partial_volume="box"))
               for k, (slices, tall, inclusion) in enumerate(CLEAR_RING_POSTS)]

    def base_errors():
        out = []
        for vol in volumes:
            seg = segment(vol.image, vol.spacing_mm, where="short post")
            assert seg.warnings == [] and seg.base_surface is not None
            out.append(base_error_mm(seg.base_surface, vol))
        return np.array(out)

    calls = []
    clear_end = pillar._clear_end
    monkeypatch.setattr(pillar, "_clear_end", lambda *a: calls.append(clear_end(*a)) or calls[-1])
    clear = base_errors()
    assert len(calls) == len(CLEAR_RING_POSTS) and None not in calls
    monkeypatch.setattr(pillar, "_clear_end", lambda *a: None)
    crossing = base_errors()
    assert np.abs(clear).mean() < np.abs(crossing).mean()
    assert abs(clear.mean()) < abs(crossing.mean())


ONE_MM_POSTS = [(slices, post, inclusion) for slices in (0.95, 1.15) for post in (2.5, 3.5)
                for inclusion in (9.0, 14.0)]


def test_a_lone_post_1mm_tall_is_found_and_fitted_across_its_gap():
    """Noise 0.02, slices 0.95 and 1.15 mm (0.8 mm across): posts 2.5 and 3.5 mm wide and 1 mm tall under
    the scan's only inclusion (9 or 14 mm): each is found, and their diameters are drawn within 0.15 mm
    (median of the absolute errors over the 8 scans).

    Six of them leave no slab between the inclusion and the base. Such a post's silicone across the gap
    was counted voxel by voxel over half-way: the blur of the ball's cap and the base's widened three
    (by 0.31-0.35 mm), and two were left unlabelled with a warning (one gap held no voxel centre, the other
    read 5.3 mm wide, past the widest pillar); it is now fitted as the posts a slab or two tall are
    (`_post_radius`). The worst of the 8 is the 3.5 mm post under the 9 mm inclusion at 1.15 mm slices:
    the ball fitted to that inclusion reaches 0.2 mm too low and takes in part of the post, drawn 0.6 mm too
    thin."""
    errors = []
    for k, (slices, post, inclusion) in enumerate(ONE_MM_POSTS):
        vol = generate(Case(seed=660 + k, spacing_mm=(slices, 0.8, 0.8), inclusion_mm=(inclusion,),
                            pillar_mm=post, pillar_height_mm=(1.0,), noise=0.02, bias=0.1,
                            partial_volume="box"))
        seg = segment(vol.image, vol.spacing_mm, where="1 mm post")
        assert seg.warnings == []
        errors.append(post_errors(seg.posts, vol)[0]["post_diameter_error_mm"])
    assert np.median(np.abs(errors)) < 0.15


@pytest.mark.parametrize("seed", [770, 776])
def test_a_ball_on_a_short_post_is_centred_on_its_sphere(seed):
    """1.19 mm slices, bias 0.2: a 10.3 mm inclusion on a 3 mm post 2 mm tall, base up. The fitted ball's
    centre lies within 0.08 mm of the sphere's along the insert axis, and the post meets pillar Dice 0.80.
    With the bias field fitted only once, with the voxels that mix the tissues at the skin, the base and
    the inclusions (`lesscli.mri.bias`, ``margin_voxels=0``), the field bent near the base and put the
    ball 0.21 mm off, the cap's slice then labelled pillar (Dice 0.55 and 0.52)."""
    vol = generate(Case(seed=seed, spacing_mm=(1.19, 1.1, 1.1), inclusion_mm=(10.3,), pillar_mm=3.0,
                        pillar_height_mm=(2.0,), base_up=True, noise=0.05, bias=0.2))
    seg = segment(vol.image, vol.spacing_mm, where="post")
    (shape,) = seg.inclusion_shapes
    axial = (shape["centre_index"][0] - vol.centres_index[0][0]) * vol.spacing_mm[0]
    assert shape["shape"] == "ball" and abs(axial) <= 0.08
    assert inclusion_scores(seg.labels, vol)[0]["dice_pillar"] >= MIN_DICE["pillar"]


def test_inclusion_without_pillar_is_labelled_with_one_warning():
    vol = generate(Case(seed=506, spacing_mm=(0.9, 0.8, 0.8), inclusion_mm=(9.0, 12.0), pillar_mm=0.0,
                        pillar_height_mm=(4.0, 8.0), noise=0.05, bias=0.2))
    seg = segment(vol.image, vol.spacing_mm, where="floating")
    assert not (seg.labels == 2).any()
    assert scores(seg.labels, vol.truth)["insert"] >= MIN_DICE["insert"]
    assert len(seg.warnings) == 2 and all("no pillar found under the inclusion" in w for w in seg.warnings)
    named = sorted(json.loads(w.split("near voxel ")[1]) for w in seg.warnings)
    expected = sorted(np.round(vol.centres_index).astype(int).tolist())
    assert np.abs(np.asarray(named) - np.asarray(expected)).max() <= 1


@pytest.mark.parametrize("seed", [11, 35, 1024, 1042])
def test_floating_family_inclusions_get_no_post_and_a_warning_each(seed):
    """Family volumes drawn without posts (`examples/mri_family.py --floating`): no pillar voxel, one warning
    naming each inclusion. On these a trace's noise passed the test on its first, wide core, and the post
    measured in its second came out thinner than MIN_RADIUS_MM (0-0.13 mm): nothing or a voxel or two was
    drawn, and the inclusion's warning was missing."""
    import dataclasses

    from mri_family import draw_case

    vol = generate(dataclasses.replace(draw_case(seed), pillar_mm=0.0))
    seg = segment(vol.image, vol.spacing_mm, where=f"seed {seed}")
    assert not (seg.labels == PILLAR).any() and seg.posts == []
    assert len(seg.warnings) == len(vol.case.inclusion_mm)
    assert all("no pillar found under the inclusion" in w for w in seg.warnings)


FLOATING_UNDER_SKIN = {     # seeds of `examples/mri_family.py --near-skin --floating --partial-volume box`
    32: Case(seed=32, spacing_mm=(0.78, 1.03, 0.76), inclusion_mm=(9.8, 12.7, 8.6), pillar_mm=0.0,
             pillar_height_mm=(12.2, 11.9, 9.0), base_up=True, silicone_brighter=True, noise=0.028,
             bias=0.369, partial_volume="box", skin_gap_mm=0.51),
    51: Case(seed=51, spacing_mm=(1.17, 1.13, 0.73), inclusion_mm=(15.1, 13.1, 6.4), pillar_mm=0.0,
             pillar_height_mm=(12.6, 14.2, 12.2), base_up=True, silicone_brighter=True, noise=0.057,
             bias=0.177, partial_volume="box", skin_gap_mm=1.37),
    97: Case(seed=97, spacing_mm=(0.79, 0.67, 0.98), inclusion_mm=(7.7, 7.0, 13.3), pillar_mm=0.0,
             pillar_height_mm=(14.1, 5.1, 2.5), base_up=False, silicone_brighter=True, noise=0.097,
             bias=0.337, partial_volume="box", skin_gap_mm=0.76),
    86: Case(seed=86, spacing_mm=(0.69, 1.03, 1.03), inclusion_mm=(14.9, 15.5, 13.0), pillar_mm=0.0,
             pillar_height_mm=(6.0, 7.6, 2.9), base_up=False, silicone_brighter=True, noise=0.096, bias=0.246,
             partial_volume="box", skin_gap_mm=1.61),
    1019: Case(seed=1019, spacing_mm=(1.07, 1.17, 1.17), inclusion_mm=(8.7, 9.6), pillar_mm=0.0,
               pillar_height_mm=(12.8, 10.9), base_up=True, silicone_brighter=False, noise=0.071, bias=0.396,
               partial_volume="box", skin_gap_mm=1.04),
}


@pytest.mark.parametrize("seed", sorted(FLOATING_UNDER_SKIN))
def test_a_floating_sphere_just_under_the_skin_gets_no_post(seed):
    """Spheres without posts, the highest 0.5-1.4 mm under the skin: no post has anything to say for the
    base's side, and the gap to the skin, or a trace of a slab or two across it, is where a post was looked
    for. With the ball taken out as fitted (its fit leaves out that cap), what was left there read as a post
    of 0.50-0.71 mm, over MIN_RADIUS_MM, and 1-6 voxels were drawn in place of a warning. The post's radius is
    now fitted with the ball's, and a post too short to measure on its own slabs must show one so fitted
    before it takes the scan's pooled radius (`section._post_radius`, `section._pooled_radii`). Under 86's and
    1019's spheres a trace of noise 10-17 mm long read a disc of 0.48 and 0.26 mm on its slabs and a cylinder
    over 0.5 mm fitted to them, and 10-11 voxels were drawn: a post must show MIN_RADIUS_MM both ways."""
    vol = generate(FLOATING_UNDER_SKIN[seed])
    seg = segment(vol.image, vol.spacing_mm, where=f"seed {seed}")
    assert not (seg.labels == PILLAR).any() and seg.posts == []
    assert len(seg.warnings) == len(vol.case.inclusion_mm)
    assert scores(seg.labels, vol.truth)["insert"] >= MIN_DICE["insert"]


def test_qc_shows_each_inclusion_with_the_pillar_outlined(run_less, tmp_path):
    import matplotlib.image as mpimg

    vol = generate(CASES["two-inclusions-thick-slices-dark-noisy"])
    affine = np.diag([*vol.spacing_mm, 1.0])
    nib.save(nib.Nifti1Image(vol.image, affine), tmp_path / "scan.nii.gz")
    run_less("mri-label", "scan.nii.gz", "-o", "labels.nii.gz", "--plot", "qc.png", check=True)
    png = mpimg.imread(tmp_path / "qc.png")
    height, width = png.shape[:2]
    assert abs(height / width - 2 * 4.2 / 12) < 0.02                # two rows of three planes
    orange = (np.abs(png[..., 0] - 1.0) < 0.1) & (np.abs(png[..., 1] - 0.6) < 0.1) & (png[..., 2] < 0.1)
    assert orange.sum() > 50                                         # the pillar outlines


@pytest.mark.parametrize("seed", [744, 745])
def test_one_slice_pillar_under_a_single_inclusion_is_found_on_the_base_side(seed):
    """1.08 mm slices, low noise: a 3.8 mm pillar 1.2 mm tall under a lone 15.5 mm inclusion (pillar Dice
    0.80).

    The inclusion found holds the pillar's one slice, so no slab lies between it and the base: the
    base side was then decided by the skin side's noise (wrong), and no gap was left to measure the
    post in (not found). The short silicone gap now marks the base side where no post is significant,
    and the inclusion's voxels beyond its fitted ball are the pillar's."""
    vol = generate(Case(seed=seed, spacing_mm=(1.08, 0.48, 0.48), inclusion_mm=(15.5,), pillar_mm=3.81,
                        pillar_height_mm=(1.2,), silicone_brighter=True, noise=0.023, bias=0.311))
    seg = segment(vol.image, vol.spacing_mm, where="one slice")
    assert seg.warnings == []
    assert all(row["dice_pillar"] >= MIN_DICE["pillar"] for row in inclusion_scores(seg.labels, vol))


def _lone_post_dice(case: Case) -> float:
    """The pillar Dice of a scan with one inclusion, whose post is found (no warning) and whose inclusion
    meets the target."""
    vol = generate(case)
    seg = segment(vol.image, vol.spacing_mm, where=f"seed {case.seed}")
    assert seg.warnings == [], case.seed
    (row,) = inclusion_scores(seg.labels, vol)
    assert row["dice_inclusion"] >= MIN_DICE["inclusion"], case.seed
    return row["dice_pillar"]


SHORT_POSTS_THICK_SLICES = [          # seed, slices, post, tall, inclusion (mm), base up, silicone brighter
    (901, 1.0, 2.5, 1.0, 10.0, False, True), (913, 1.0, 2.5, 1.4, 12.0, False, True),
    (919, 1.0, 3.0, 1.0, 10.0, True, True), (931, 1.0, 3.0, 1.4, 12.0, True, True),
    (934, 1.15, 2.5, 1.0, 10.0, False, False), (937, 1.15, 2.5, 1.0, 12.0, False, True),
    (955, 1.15, 3.0, 1.0, 12.0, True, True), (961, 1.15, 3.0, 1.4, 12.0, False, True)]


def test_short_posts_at_thick_slices_are_each_found():
    """Noise 0.04, bias 0.2, slices 1.0 and 1.15 mm (1.2 mm across): posts 2.5 and 3 mm wide, 1 and 1.4 mm
    tall, under one 10 or 12 mm inclusion. Each post is found, each inclusion meets Dice 0.93 and the median
    pillar Dice 0.80.

    Four of the eight were left without a post (the inclusion read 0.89 on one):
    - over a post a slab or so tall the inclusion's body can run on through it into the base, and its gap
      to the base then ends where the ring leaves the insert: the one voxel left on its axis, half silicone
      and half air, read as hydrogel, and the gap counted as holding no post; the voxels in partial volume
      with the air now decide nothing;
    - a bias field curved across the column raised the skin side's wide core over its ring by about 1 mm^2
      in every slab, which passed as a post there, and the side with a post outweighed the gap's silicone;
      an inclusion with a short gap holding silicone now counts that gap's post, not its other side;
    - the body's voxels run on past the ball took the base's silicone into the ball's fit (0.2 mm into the
      post) and, drawn from the image's surface, into the inclusion."""
    dice = [_lone_post_dice(Case(seed=seed, spacing_mm=(slices, 1.2, 1.2), inclusion_mm=(inclusion,),
                                 pillar_mm=post, pillar_height_mm=(tall,), base_up=base_up,
                                 silicone_brighter=brighter, noise=0.04, bias=0.2, partial_volume="box"))
            for seed, slices, post, tall, inclusion, base_up, brighter in SHORT_POSTS_THICK_SLICES]
    assert np.median(dice) >= MIN_DICE["pillar"]


def test_a_short_post_in_a_scan_without_noise_is_found():
    """Noise 0.005 and no bias, 1.11 mm slices: a 2.7 mm post 1.2 mm tall under a lone 11.4 mm inclusion,
    base up or down, both contrasts. Each post is found and its inclusion meets Dice 0.93; the median
    pillar Dice is 0.80.

    Without noise the inclusion's body ran on through the post into the base on half of them; one post was
    not found (its gap's last voxel, half air, read as hydrogel) and another drawn 0.6 mm thin."""
    dice = [_lone_post_dice(Case(seed=seed, spacing_mm=(1.11, 1.19, 1.19), inclusion_mm=(11.4,),
                                 pillar_mm=2.7, pillar_height_mm=(1.2,), base_up=bool(seed % 2),
                                 silicone_brighter=seed % 3 != 0, noise=0.005, bias=0.0,
                                 partial_volume="box"))
            for seed in range(980, 986)]
    assert np.median(dice) >= MIN_DICE["pillar"]


def _inclusion_dice(vol, shape: str) -> tuple[list[float], np.ndarray]:
    from lesscli.mri.segment import SegmentParams

    seg = segment(vol.image, vol.spacing_mm, SegmentParams(inclusion_shape=shape), where=shape)
    assert seg.warnings == []
    return [row["dice_inclusion"] for row in inclusion_scores(seg.labels, vol)], seg.labels


@pytest.mark.parametrize("seed", [810, 812])
def test_noisy_small_balls_take_their_fitted_ball(seed):
    """1 mm voxels, noise 0.08: a 7 and an 11 mm inclusion, each a ball, meet Dice 0.96 (auto = ball).

    Their surfaces re-thresholded from the image scatter with the noise (Dice 0.93-0.95); the fitted
    blurred ball explains the voxels near each as well as the noise allows, so it is taken instead."""
    vol = generate(Case(seed=seed, spacing_mm=(1.0, 0.9, 0.9), inclusion_mm=(7.0, 11.0), pillar_mm=2.5,
                        pillar_height_mm=(4.0, 8.0), noise=0.08, bias=0.2))
    auto, auto_labels = _inclusion_dice(vol, "auto")
    image, _ = _inclusion_dice(vol, "image")
    _ball, ball_labels = _inclusion_dice(vol, "ball")
    assert min(auto) >= 0.96 and np.mean(auto) > np.mean(image) + 0.01
    np.testing.assert_array_equal(auto_labels, ball_labels)


def test_a_spheroid_keeps_the_image_surface():
    """Inclusions 1.4 times longer along one axis than across: the ball misfits them, auto keeps the
    image's surface (the same labels as "image", Dice 0.92), and forcing the ball costs 0.05."""
    vol = generate(Case(seed=811, spacing_mm=(1.0, 0.9, 0.9), inclusion_mm=(7.0, 11.0), pillar_mm=2.5,
                        pillar_height_mm=(4.0, 8.0), noise=0.08, bias=0.2, inclusion_aspect=1.4))
    auto, auto_labels = _inclusion_dice(vol, "auto")
    _image, image_labels = _inclusion_dice(vol, "image")
    ball, _ = _inclusion_dice(vol, "ball")
    np.testing.assert_array_equal(auto_labels, image_labels)
    assert min(auto) >= 0.92 and all(a >= b + 0.05 for a, b in zip(auto, ball))


FACE_CASES = {
    # 1.11 mm slices under 1.19 mm voxels, bright skin: the layer the skin's level is read in (1-2 mm deep
    # then) held no slice at the end faces, which kept the global dark-tissue threshold there (0.972 before)
    "bright-skin-1.11mm-slices": Case(seed=763, spacing_mm=(1.11, 1.19, 1.19), inclusion_mm=(11.4,),
                                      pillar_mm=2.7, pillar_height_mm=(6.0,), silicone_brighter=True,
                                      noise=0.044, bias=0.2),
    # dark skin at noise 0.094: air reads the noise's mean, and half-way between it and the skin lay a
    # tenth of the contrast above a half-filled voxel; the end faces came out a slice inside (0.966, 0.969)
    "dark-skin-noisy-a": Case(seed=763, spacing_mm=(1.0, 0.98, 0.98), inclusion_mm=(10.4,), pillar_mm=3.9,
                              pillar_height_mm=(9.8,), noise=0.094, bias=0.2),
    "dark-skin-noisy-b": Case(seed=772, spacing_mm=(1.0, 0.98, 0.98), inclusion_mm=(10.4,), pillar_mm=3.9,
                              pillar_height_mm=(9.8,), noise=0.094, bias=0.2),
}


@pytest.mark.parametrize("name", sorted(FACE_CASES))
def test_outer_surface_end_faces_within_a_slice(name):
    """The insert's top and bottom faces (across the slices) land on the right slice: insert Dice 0.975."""
    vol = generate(FACE_CASES[name])
    seg = segment(vol.image, vol.spacing_mm, where=name)
    assert scores(seg.labels, vol.truth)["insert"] >= 0.975


@pytest.mark.parametrize("spacing", [(0.9, 1.1, 1.1), (1.2, 0.8, 0.8)])
def test_box_partial_volume_keeps_a_thin_posts_silicone_and_the_ramp_adds_to_it(spacing):
    """The family's generator itself: without noise and bias a post's silicone per slice (the blur
    keeps its sum) is its disc's area under the box partial volume (within 2 %), while the ramp's fill
    adds to it (the bias of the ramp family described in docs/results/mri-label-family.md)."""
    diameter = 1.8
    excess = {}
    for pv in ("box", "ramp"):
        case = Case(seed=3, spacing_mm=spacing, inclusion_mm=(10.0,), pillar_mm=diameter,
                    pillar_height_mm=(12.0,), noise=0.0, bias=0.0, silicone_brighter=True, yaw_deg=17.0,
                    partial_volume=pv)
        vol = generate(case)
        post = vol.truth == PILLAR
        rows = np.nonzero(post.any(axis=(1, 2)))[0][3:-3]           # slabs away from the base and the ball
        centre = np.argwhere(post[rows[0]]).mean(axis=0)
        a1, a2 = np.ogrid[:post.shape[1], :post.shape[2]]
        r = np.hypot((a1 - centre[0]) * spacing[1], (a2 - centre[1]) * spacing[2])
        disc = r < 4.0
        gel = np.median(vol.image[rows][:, (r > 3.0) & disc])         # the filling's level around the post
        share = (vol.image[rows][:, disc] - gel) / (1.0 - gel)        # silicone share (silicone_brighter: 1)
        area = share.sum(axis=1).mean() * spacing[1] * spacing[2]
        excess[pv] = area / (np.pi * diameter ** 2 / 4) - 1
    assert abs(excess["box"]) < 0.02
    assert excess["ramp"] > 0.05


@pytest.mark.parametrize("offset, same", [(0.05, True), (0.08, False)])
def test_box_partial_volume_leaves_a_flat_surface_near_a_voxel_centre_undecided(offset, same):
    """The family's generator itself: a flat surface within half the box's sub-voxel step (1/16 of a voxel
    at 8 points) of a plane of voxel centres gives the same shares on either side of it, though the
    truth, which classifies the centres, differs; a little further out they differ too. This is the band
    `Volume.undecided_slices` leaves out of `dice_pillar_decided`."""
    import mri_family

    shape, centre = (9, 3, 3), 4.0
    grid = [np.arange(n, dtype=float) for n in shape]
    a0 = np.broadcast_to(grid[0][:, None, None], shape)

    def shares(level):
        def at(p0, p1, p2):
            return -np.ones(np.shape(p0)), p0 - level         # inside the body; silicone up to ``level``
        return mri_family._box_fills(-np.ones(shape), a0 - level, grid, np.ones(3), at)[0]

    below, above = shares(centre - offset), shares(centre + offset)
    # the truth moves
    assert (a0[:, 0, 0] <= centre - offset).sum() != (a0[:, 0, 0] <= centre + offset).sum()
    assert np.array_equal(below, above) == same
    assert 0.05 < 0.5 / mri_family.BOX_POINTS < 0.08          # the two offsets bracket the band


@pytest.mark.parametrize("voxel_mm, radius_mm", [(0.8, 0.75), (1.1, 0.75), (1.1, 1.5)])
def test_the_ramp_draws_a_post_as_a_wider_one_the_scan_cannot_tell_apart(voxel_mm, radius_mm):
    """The family's generator itself: a vertical post under each partial volume and the generator's blur, with
    no noise, fitted by the segmenter's own model (`cylinder.fit_blurred_cylinder`, the blurred disc it draws
    posts by). Under the box the fit finds the post's radius; under the ramp, whose fill adds silicone around
    a curved surface, one wider by about voxel^2 / (24 radius), and the profile fits that wider disc as
    closely as the box's fits the true one, far inside the family's least noise (0.02 of the brighter
    tissue, 0.03 of the contrast or more): no reading of the scan tells the ramp's post from a wider one,
    and the ramp's misses on docs/results/mri-label-family.md are its own."""
    import mri_family
    from scipy import ndimage

    from lesscli.mri.cylinder import _cylinder_misfit, fit_blurred_cylinder

    spacing = np.array([voxel_mm, voxel_mm, 1.0])
    n, offset = 15, np.array([0.23, -0.31]) * voxel_mm      # the post's axis off the voxel centres
    grid = [(np.arange(m) - m // 2) * s for m, s in zip((n, n, 5), spacing)]
    x, y, _z = np.meshgrid(*grid, indexing="ij")
    post = np.hypot(x - offset[0], y - offset[1]) - radius_mm

    def at(p0, p1, p2):
        return np.hypot(p0 - offset[0], p1 - offset[1]) - radius_mm, np.zeros(np.shape(p0))

    fills = {"ramp": mri_family._fill(post, spacing),
             "box": mri_family._box_fills(post, np.zeros(post.shape), grid, spacing, at)[1]}
    fitted = {}
    for name, fill in fills.items():
        excess = ndimage.gaussian_filter(fill, sigma=0.5)[..., 2].ravel()  # the generator's blur; one slice
        uv = np.column_stack([x[..., 2].ravel(), y[..., 2].ravel()])
        t = np.zeros(len(excess))
        line, radius, blur = fit_blurred_cylinder(uv, t, excess, np.zeros((2, 2)), 1.0, 0.5 * voxel_mm, 3.0)
        assert float(np.sqrt(np.mean(_cylinder_misfit(uv, t, excess, line, radius, blur) ** 2))) < 0.01
        fitted[name] = radius
    wider = voxel_mm ** 2 / (24 * radius_mm)
    assert abs(fitted["box"] - radius_mm) < 0.02
    assert 0.5 * wider < fitted["ramp"] - radius_mm < 3.0 * wider


@pytest.mark.parametrize("base_up", [False, True])
def test_volume_base_index_is_where_the_truths_pillar_starts(base_up):
    """`Volume.base_index`: the pillar's truth holds the slices on the filling's side of it and none past
    it."""
    vol = generate(Case(seed=7, spacing_mm=(0.83, 0.9, 0.9), pillar_height_mm=(4.0,), base_up=base_up,
                        noise=0.0))
    rows = np.nonzero((vol.truth == PILLAR).any(axis=(1, 2)))[0]
    nearest = rows.max() if base_up else rows.min()                 # the pillar's slice next to the base
    assert 0.0 < (vol.base_index - nearest) * (1 if base_up else -1) < 1.0


@pytest.mark.parametrize("base_up", [False, True])
def test_volume_outer_indices_bound_the_truths_insert(base_up):
    """`Volume.outer_indices`: the truth's insert holds the slices between the two faces and none past
    them."""
    vol = generate(Case(seed=7, spacing_mm=(0.83, 0.9, 0.9), base_up=base_up, noise=0.0), image=False)
    rows = np.nonzero((vol.truth > 0).any(axis=(1, 2)))[0]
    lo, hi = sorted(vol.outer_indices())
    assert rows.min() == np.ceil(lo) and rows.max() == np.floor(hi)
    assert abs(abs(hi - lo) * 0.83 - vol.height_mm) < 1e-9


@pytest.mark.parametrize("gap, left_out", [(0.05, True), (0.08, False)])
def test_insert_scores_leave_out_a_slice_undecided_at_an_outer_face(gap, left_out):
    """`insert_scores`: the slice whose centres lie within the box's half sub-voxel step of an outer face
    (moved there, the truth as drawn) is left out of `dice_insert_decided`, and one a little further is not;
    `dice_insert`
    keeps it."""
    import dataclasses

    vol = generate(Case(seed=7, spacing_mm=(0.83, 0.9, 0.9), partial_volume="box"), image=False)
    first = int(np.nonzero((vol.truth > 0).any(axis=(1, 2)))[0].min())
    moved = dataclasses.replace(vol, base_index=vol.base_index + first - gap - min(vol.outer_indices()))
    assert min(moved.outer_indices()) == pytest.approx(first - gap)
    labels = vol.truth.copy()
    labels[first] = 0                                           # that slice missed
    got = insert_scores(labels, moved)
    assert got["dice_insert"] < 0.99
    assert (got["dice_insert_decided"] == 1.0) == left_out
    assert insert_scores(vol.truth, moved) == {"dice_insert": 1.0, "dice_insert_decided": 1.0}


def test_family_script_rows_and_footer(tmp_path):
    """`examples/mri_family.py` (the table and counts of docs/results/mri-label-family.md): one box volume,
    its rows and the footer."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    proc = subprocess.run([sys.executable, str(script), "--seeds", "2001", "--partial-volume", "box", "--out",
                           str(tmp_path / "rows.jsonl")], capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    (case,) = [r for r in rows if r["row"] == "case"]
    assert abs(case["base_error_mm"]) < 0.25 * case["spacing_mm"][0]
    assert all(0.0 <= r["dice_pillar_decided"] <= 1.0 for r in rows if r["row"] == "inclusion")
    assert 0.0 <= case["dice_insert_decided"] <= 1.0
    assert "Volumes meeting all three targets:" in proc.stdout and "of 1" in proc.stdout
    again = subprocess.run([sys.executable, str(script), "--rows", str(tmp_path / "rows.jsonl")],
                           capture_output=True, text=True, check=True)
    assert again.stdout == proc.stdout          # --rows: the table of rows written before, nothing segmented
    missing = subprocess.run([sys.executable, str(script), "--rows",
                              f"{tmp_path / 'rows.jsonl'},{tmp_path / 'no'}"],
                             check=False, capture_output=True, text=True)
    assert missing.returncode == 1 and missing.stdout == ""
    assert missing.stderr.count("\n") == 1 and str(tmp_path / "no") in missing.stderr


def test_family_script_lone_short(tmp_path):
    """`examples/mri_family.py --lone-short` (the set `ball.CAP_SHUT_VOXELS` was chosen on): the case's first
    inclusion alone on a post 1-2.5 mm tall, and the footer's diameter error of the posts found."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    proc = subprocess.run([sys.executable, str(script), "--seeds", "900", "--partial-volume", "box",
                           "--lone-short", "--out", str(tmp_path / "rows.jsonl")], capture_output=True,
                           text=True, check=True)
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    (inclusion,) = [r for r in rows if r["row"] == "inclusion"]
    assert (inclusion["inclusion_mm"] == draw_case(900).inclusion_mm[0]
            and 1.0 <= inclusion["pillar_height_mm"] <= 2.5)
    assert "Post diameter error: mean" in proc.stdout and "(1 posts)" in proc.stdout


def test_family_script_near_skin(tmp_path):
    """`examples/mri_family.py --near-skin`: the highest sphere 0.5-2 mm under the skin, the first inclusion's
    post no taller than the family's tallest; the rows and the table keep the gap."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    proc = subprocess.run([sys.executable, str(script), "--seeds", "3", "--near-skin", "--out",
                           str(tmp_path / "rows.jsonl")], capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    (case,) = [r for r in rows if r["row"] == "case"]
    first = next(r for r in rows if r["row"] == "inclusion")
    drawn = draw_case(3)
    assert 0.5 <= case["skin_gap_mm"] <= 2.0 and first["pillar_height_mm"] <= 15.0
    assert (first["pillar_height_mm"] >= drawn.pillar_height_mm[0]
            and first["inclusion_mm"] >= drawn.inclusion_mm[0])
    assert "| highest sphere under the skin (mm) |" in proc.stdout
    clash = subprocess.run([sys.executable, str(script), "--seeds", "3", "--near-skin", "--lone-short"],
                           check=False, capture_output=True, text=True)
    assert clash.returncode == 2 and "not allowed with" in clash.stderr


def test_family_script_tilted(tmp_path):
    """`examples/mri_family.py --tilted`: each volume's insert axis 0-10 degrees off the array's first axis;
    the
    rows keep the tilt and the table gives its bands."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    proc = subprocess.run([sys.executable, str(script), "--seeds", "3", "--tilted", "--out",
                           str(tmp_path / "rows.jsonl")],
                          capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    assert {r["tilt_deg"] for r in rows} == {rows[0]["tilt_deg"]} and 0.0 < rows[0]["tilt_deg"] <= 10.0
    assert "| insert axis tilt (degrees) |" in proc.stdout


def test_family_script_small_coarse(tmp_path):
    """`examples/mri_family.py --small-coarse` (the probes in docs/results/mri-label-rounds.md of small
    spheres at coarse voxels): the volume drawn from ``[seed // 100, seed % 100]``, its first sphere 6-7 mm,
    every voxel side 0.9-1.2 mm, noise
    0.05-0.1."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    subprocess.run([sys.executable, str(script), "--seeds", "4901,49201", "--small-coarse", "--out",
                    str(tmp_path / "rows.jsonl")], capture_output=True, text=True, check=True)
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    cases = [r for r in rows if r["row"] == "case"]
    assert [c["seed"] for c in cases] == [4901, 49201]
    for case in cases:
        first = next(r for r in rows if r["row"] == "inclusion" and r["seed"] == case["seed"])
        assert 6.0 <= first["inclusion_mm"] <= 7.0 and 0.05 <= case["noise"] <= 0.1
        assert all(0.9 <= s <= 1.2 for s in case["spacing_mm"])
    assert cases[0]["spacing_mm"] != cases[1]["spacing_mm"]


def test_family_script_known_diameter(tmp_path):
    """`examples/mri_family.py --known-diameter`: the volume segmented with its posts' true diameter given;
    the rows' diameter error stays that of the diameter the scan measured, the post drawn as wide as given
    (seed 6058's 2.4 voxels wide, measured 0.2 mm too wide: 35 voxels drawn, 28 given its diameter)."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    rows = {}
    for name, extra in (("measured", []), ("given", ["--known-diameter"])):
        subprocess.run([sys.executable, str(script), "--seeds", "6058", "--partial-volume", "box", *extra,
                        "--out", str(tmp_path / f"{name}.jsonl")], capture_output=True, text=True, check=True)
        rows[name] = [json.loads(line) for line in (tmp_path / f"{name}.jsonl").read_text().splitlines()]
    (measured,), (given,) = ([r for r in rows[n] if r["row"] == "inclusion"] for n in ("measured", "given"))
    assert given["post_diameter_error_mm"] == measured["post_diameter_error_mm"] != 0.0
    assert given["post_height_error_mm"] == measured["post_height_error_mm"]
    pillar_voxels = [next(r for r in rows[n] if r["row"] == "case")["pillar_voxels_drawn"]
                     for n in ("measured", "given")]
    assert pillar_voxels[0] != pillar_voxels[1]


@pytest.mark.parametrize("base_up", [False, True])
def test_perturbed_case_moves_only_the_post_and_the_base(base_up):
    """`perturbed`: the same layout and draws; the base's surface moves by the given mm into the filling, the
    posts widen by the given radius, the spheres grow about their centres; with no change the truth is the
    same array."""
    case = Case(seed=11, spacing_mm=(0.8, 0.7, 0.7), inclusion_mm=(10.0, 7.0), pillar_height_mm=(5.0, 9.0),
                base_up=base_up, noise=0.0)
    vol = generate(case)
    assert np.array_equal(generate(perturbed(case)).truth, vol.truth)
    up = generate(perturbed(case, base_mm=0.4))
    assert np.allclose(up.centres_index, vol.centres_index)
    assert (up.base_index - vol.base_index) * (-1 if base_up else 1) == pytest.approx(0.4 / 0.8)
    wide = generate(perturbed(case, radius_mm=0.3))
    assert np.allclose(wide.centres_index, vol.centres_index)
    assert (wide.truth == PILLAR).sum() > (vol.truth == PILLAR).sum()
    grown = generate(perturbed(case, sphere_mm=0.3))
    assert np.allclose(grown.centres_index, vol.centres_index) and grown.base_index == vol.base_index
    assert (grown.truth == INCLUSION).sum() > (vol.truth == INCLUSION).sum()
    assert ((grown.truth == INCLUSION) | (vol.truth != INCLUSION)).all()
    assert (grown.truth == PILLAR).sum() < (vol.truth == PILLAR).sum()


def test_family_script_margins(tmp_path):
    """`examples/mri_family.py --margins`: zero perturbation leaves every pillar's Dice 1; the table counts
    the volumes a perturbation takes below the target (seed 4058: a ring of voxel centres lies within
    0.025 mm outside its first post)."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "mri_family.py"
    proc = subprocess.run([sys.executable, str(script), "--seeds", "4058", "--margins", "0,0.025", "--out",
                           str(tmp_path / "rows.jsonl")], capture_output=True, text=True, check=True)
    (row,) = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()]
    assert all(d == 1.0 for key in ("radius+0", "radius-0", "base+0", "base-0", "sphere+0", "sphere-0")
               for d in row[key])
    assert min(row["radius+0.025"]) < 0.8 <= min(row["radius-0.025"])
    assert "| 0 | 0 | 0 | 0 | 0 |  |" in proc.stdout and "| 0.025 | 1 | 0 | 0 | 1 | 4058 |" in proc.stdout
