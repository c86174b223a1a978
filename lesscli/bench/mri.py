"""``less bench mri``: seconds to label a synthetic MRI volume (256^3 by default) on one core.

Baseline measured in the same run: plain three-class thresholding of the raw volume (multi-Otsu on a
sample, then one comparison per voxel), the cheapest step any segmentation needs. The full pipeline's
time is reported as a ratio to it (wall seconds; ``cpu_seconds`` is this process's CPU time, lower than
the wall time when others share the core), with the Dice per class against the synthetic truth.
"""

from __future__ import annotations

import os
import time

FULL_SIZE, QUICK_SIZE = 256, 96
FIELD_OF_VIEW_MM = 76.8          # the posed phantom (66 mm across corners, 30 mm tall) fits with air around


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


def run_mri(n: int, insert_name: str, contrast: str, seed: int) -> list[dict]:
    """Three rows for an ``n``^3 volume: the full pipeline, plain thresholding, and synthesis (untimed against).

    Call :func:`one_core` first (before numpy starts its thread pools) for a one-core number.
    """
    import numpy as np

    from lesscli.metrics import dice
    from lesscli.mri.segment import segment
    from lesscli.mri.synth import MRIParams, find_phantom, synthesize

    spacing = FIELD_OF_VIEW_MM / n
    params = MRIParams(spacing_mm=(spacing,) * 3, shape=(n, n, n), supersample=1 if n > 160 else 2,
                       silicone_brighter=contrast == "silicone-brighter", max_shift_mm=1.0)
    t0 = time.perf_counter()
    synth = synthesize(find_phantom(insert_name), np.random.default_rng(seed), params)
    t_synth = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    _threshold_only(synth.image)
    t_base, c_base = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    seg = segment(synth.image, synth.labels.spacing_mm)
    t_full, c_full = time.perf_counter() - t0, time.process_time() - c0
    truth = synth.labels.data
    scores = {f"dice_{name}": dice(seg.labels == code, truth == code)
              for code, name in ((1, "insert"), (2, "pillar"), (3, "inclusion"))}
    common = {"shape": f"{n}x{n}x{n}", "spacing_mm": round(spacing, 4), "insert": insert_name, "contrast": contrast}
    return [
        {"bench": "mri", "case": "label volume (full pipeline)", **common, "seconds": t_full, "cpu_seconds": c_full,
         "ratio_vs_threshold": t_full / t_base, **scores, "warnings": len(seg.warnings)},
        {"bench": "mri", "case": "baseline: plain 3-class thresholding", **common, "seconds": t_base, "cpu_seconds": c_base,
         "ratio_vs_threshold": 1.0},
        {"bench": "mri", "case": "synthesise the volume (not timed against)", **common, "seconds": t_synth},
    ]
