"""Segmentation accuracy of `lesscli.mri` on synthetic MRI volumes (fixed seeds), and the phantom-frame grid.

Acceptance: Dice >= 0.95 inclusion, >= 0.85 pillar, >= 0.97 insert over contrasts (silicone brighter
and darker), noise levels, bias fields, random rigid poses, 1-3 inclusions of 6-16 mm, pillars of 2-4 mm.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lesscli.io.labels import INCLUSION, INSERT, PILLAR
from lesscli.metrics import dice
from lesscli.mri.frame import find_frame, resample, up_hint_from
from lesscli.mri.scan import zyx_affine
from lesscli.mri.segment import segment
from lesscli.mri.synth import MRIParams, synthesize
from lesscli.phantom.geometry import Phantom, Pillar, Sphere

MIN_DICE = {INSERT: 0.97, PILLAR: 0.85, INCLUSION: 0.95}
SKIN_GAP_MM = 3.5               # skin 2 mm + 1.5 mm of filling above each inclusion


def hanging_phantom(placements: list[tuple[float, float, float]], pillar_diameter_mm: float) -> Phantom:
    """Inclusions (x, y, diameter mm) just under the skin, each on a pillar down to the base."""
    spheres, pillars = [], []
    for x, y, d in placements:
        z = -(SKIN_GAP_MM + d / 2)
        spheres.append(Sphere((x, y, z), d / 2))
        pillars.append(Pillar(x, y, z, pillar_diameter_mm / 2))
    return Phantom("T", inclusions=tuple(spheres), pillars=tuple(pillars))


# (inclusions (x, y, diameter), pillar diameter, synthetic MRI parameters, seed)
CASES = {
    "one-10mm-dark-lownoise": ([(9.0, 6.0, 10.0)], 2.4, {"noise_sigma": 0.02, "bias_amplitude": 0.1}, 0),
    "one-6mm-bright-noisy": ([(-7.0, 8.0, 6.0)], 2.0, {"silicone_brighter": True, "noise_sigma": 0.08}, 1),
    "two-6-16mm-dark-bias": ([(-12.0, 3.0, 6.0), (8.0, -6.0, 16.0)], 2.0,
                             {"noise_sigma": 0.05, "bias_amplitude": 0.4}, 2),
    "three-bright-4mm-pillars": ([(-13.0, -6.0, 8.0), (12.0, -8.0, 12.0), (0.0, 13.0, 14.0)], 4.0,
                                 {"silicone_brighter": True, "noise_sigma": 0.05, "bias_amplitude": 0.3,
                                      "max_tilt_deg": 10.0}, 3),
    "three-dark-3mm-tilted": ([(-12.0, 8.0, 10.0), (12.0, 8.0, 7.0), (0.0, -12.0, 12.0)], 3.0,
                              {"noise_sigma": 0.04, "bias_amplitude": 0.25, "max_tilt_deg": 12.0}, 4),
}


@pytest.fixture(scope="module")
def volumes() -> dict:
    """Each case synthesised and segmented once for all tests of this module."""
    out = {}
    for name, (placements, pillar_d, kw, seed) in CASES.items():
        phantom = hanging_phantom(placements, pillar_d)
        synth = synthesize(phantom, np.random.default_rng(seed), MRIParams(**kw))
        out[name] = (phantom, synth, segment(synth.image, synth.labels.spacing_mm, where=name))
    return out


@pytest.mark.parametrize("name", sorted(CASES))
def test_dice_per_class_meets_acceptance(volumes, name):
    _, synth, seg = volumes[name]
    for code, floor in MIN_DICE.items():
        score = dice(seg.labels == code, synth.labels.data == code)
        assert score is not None and score >= floor, f"{name}: class {code} Dice {score} < {floor}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_contrast_detected_and_no_false_warnings(volumes, name):
    _, synth, seg = volumes[name]
    assert seg.silicone_brighter == synth.params.silicone_brighter
    assert seg.warnings == []


def test_one_component_per_inclusion(volumes):
    from scipy import ndimage

    for name, (phantom, _, seg) in volumes.items():
        assert ndimage.label(seg.labels == INCLUSION)[1] == len(phantom.inclusions), name


@pytest.mark.parametrize("name", ["one-10mm-dark-lownoise", "three-bright-4mm-pillars"])
def test_phantom_grid_matches_rasterised_geometry_in_all_orientations(volumes, name):
    phantom, synth, seg = volumes[name]
    affine = zyx_affine(synth.labels.origin_mm, synth.labels.spacing_mm)
    frame = find_frame(seg.labels, affine, up_hint_from(seg.labels, seg.silicone, affine))
    true_axis = synth.rotation[:, 2]
    assert math.degrees(math.acos(min(1.0, float(frame.axes[:, 2] @ true_axis)))) < 1.0
    assert abs(frame.width_mm - phantom.width_mm) < 1.0 and abs(frame.height_mm - phantom.height_mm) < 1.0
    offset = round(synth.yaw_deg / 45.0) % 8      # orientation 0 = flats nearest the scanner axes
    for k in (0, 3, 5):
        grid = resample(seg.labels, affine, frame, orientation=k)
        truth = phantom.rotated((offset + k) % 8).label_volume()
        assert grid.shape == (26, 128, 128)
        np.testing.assert_allclose(grid.origin_mm, truth.origin_mm)
        assert dice(grid.data == INCLUSION, truth.data == INCLUSION) >= 0.9
        assert dice(grid.data > 0, truth.data > 0) >= 0.95
