"""``less bench mri``: seconds to label a synthetic MRI volume (256^3 by default) on one core.

Baseline measured in the same run: plain three-class thresholding of the raw volume (multi-Otsu on a
sample, then one comparison per voxel), the cheapest step any segmentation needs. The full pipeline's
time is reported as a ratio to it (wall seconds; ``cpu_seconds`` is this process's CPU time, lower than
the wall time when others share the core), with the Dice per class against the synthetic truth.

With ``knobs`` (:func:`run_knobs`), the same volume is labelled once per setting of each of
``less mri-label``'s knobs that trade accuracy for time, one knob changed at a time from the defaults
(:data:`KNOBS`), each row with its seconds against the defaults' in the same run and its Dice per class.
"""

from __future__ import annotations

import os
import time

FULL_SIZE, QUICK_SIZE = 256, 96
FIELD_OF_VIEW_MM = 76.8          # the posed phantom (66 mm across corners, 30 mm tall) fits with air around
# less mri-label's knobs (SegmentParams fields) and the settings tried; smoothing in units of the finest voxel
KNOBS = {"bias_degree": (0, 1, 2, 3), "smooth_voxels": (0.0, 0.3, 0.6, 1.0),
         "inclusion_shape": ("auto", "image", "ball")}
CLASSES = ((1, "insert"), (2, "pillar"), (3, "inclusion"))


def one_core() -> None:
    """Pin BLAS/OpenMP pools to one thread so the number means 'one core' (before numpy loads them)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass


def _threshold_only(image):
    import numpy as np
    from skimage.filters import threshold_multiotsu

    flat = image.ravel()
    sample = flat[np.random.default_rng(0).integers(0, flat.size, 400_000)]
    t = threshold_multiotsu(sample, classes=3)
    return np.digitize(image, t).astype(np.uint8)


def _synthesise(n: int, insert_name: str, contrast: str, seed: int):
    """(the synthetic ``n``^3 scan, seconds it took, the rows' common columns)."""
    import numpy as np

    from lesscli.mri.synth import MRIParams, find_phantom, synthesize

    spacing = FIELD_OF_VIEW_MM / n
    params = MRIParams(spacing_mm=(spacing,) * 3, shape=(n, n, n), supersample=1 if n > 160 else 2,
                       silicone_brighter=contrast == "silicone-brighter", max_shift_mm=1.0)
    t0 = time.perf_counter()
    synth = synthesize(find_phantom(insert_name), np.random.default_rng(seed), params)
    common = {"shape": f"{n}x{n}x{n}", "spacing_mm": round(spacing, 4), "insert": insert_name,
              "contrast": contrast}
    return synth, time.perf_counter() - t0, common


def _label(synth, params=None) -> tuple[float, float, dict, int]:
    """(wall seconds, CPU seconds, Dice per class against the truth, warnings) of one labelling of
    ``synth``."""
    from lesscli.metrics import dice
    from lesscli.mri.segment import SegmentParams, segment

    t0, c0 = time.perf_counter(), time.process_time()
    seg = segment(synth.image, synth.labels.spacing_mm, params or SegmentParams())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    truth = synth.labels.data
    return wall, cpu, {f"dice_{name}": dice(seg.labels == code, truth == code) for code, name in CLASSES}, \
        len(seg.warnings)


def run_mri(n: int, insert_name: str, contrast: str, seed: int) -> list[dict]:
    """Four rows for an ``n``^3 volume: the full pipeline, plain thresholding, the pipeline's first call in
    the process, and synthesis (untimed against).

    Each of the two compared is timed on its second call: the first pays the modules each imports on first
    use (a tenth of a second, a fifth of the pipeline itself at 96^3), which is reported in its own row, as
    every `less mri-label` run pays it once. Call :func:`one_core` first (before numpy starts its thread
    pools) for a one-core number.
    """
    synth, t_synth, common = _synthesise(n, insert_name, contrast, seed)
    t_first, c_first = _label(synth)[:2]
    _threshold_only(synth.image)
    t0, c0 = time.perf_counter(), time.process_time()
    _threshold_only(synth.image)
    t_base, c_base = time.perf_counter() - t0, time.process_time() - c0
    t_full, c_full, scores, warnings = _label(synth)
    return [
        {"bench": "mri", "case": "label volume (full pipeline)", **common, "seconds": t_full,
         "cpu_seconds": c_full, "ratio_vs_threshold": t_full / t_base, **scores, "warnings": warnings},
        {"bench": "mri", "case": "baseline: plain 3-class thresholding", **common, "seconds": t_base,
         "cpu_seconds": c_base, "ratio_vs_threshold": 1.0},
        {"bench": "mri", "case": "label volume, first call in the process (imports included)", **common,
         "seconds": t_first, "cpu_seconds": c_first, "ratio_vs_threshold": t_first / t_base},
        {"bench": "mri", "case": "synthesise the volume (not timed against)", **common, "seconds": t_synth},
    ]


def run_knobs(n: int, insert_name: str, contrast: str, seed: int) -> list[dict]:
    """One row per setting of each knob of :data:`KNOBS` (the others at their defaults) on one synthetic
    ``n``^3 volume: ``knob``, ``value``, wall and CPU seconds, ``ratio_vs_default`` (against the defaults,
    timed first in the same run, after one untimed labelling; a knob's default setting is that row again),
    Dice per class and its difference from the defaults', and the warnings. Call :func:`one_core` first."""
    from dataclasses import replace

    from lesscli.mri.segment import SMOOTH_VOXELS, SegmentParams

    synth, _t_synth, common = _synthesise(n, insert_name, contrast, seed)
    finest = float(min(synth.labels.spacing_mm))
    default = SegmentParams()

    def params(knob, value):
        if knob == "smooth_voxels":
            return replace(default, smooth_mm=value * finest)
        return replace(default, **{knob: value})

    def is_default(knob, value):
        return value == (SMOOTH_VOXELS if knob == "smooth_voxels" else getattr(default, knob))

    _label(synth)                   # warm: the first labelling also loads the libraries it calls
    base = _label(synth)
    rows = []
    for knob, values in KNOBS.items():
        for value in values:
            wall, cpu, scores, warnings = (base if is_default(knob, value)
                                           else _label(synth, params(knob, value)))
            rows.append({"bench": "mri", "case": "knob", **common, "knob": knob, "value": value,
                         "default": is_default(knob, value), "seconds": wall, "cpu_seconds": cpu,
                         "ratio_vs_default": wall / base[0], **scores,
                         **{f"{k}_delta": v - base[2][k] for k, v in scores.items()}, "warnings": warnings})
    return rows
