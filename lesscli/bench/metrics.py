"""``less bench metrics``: time to score one 26x128x128 volume with a 16 mm inclusion.

Baselines measured in the same run: the F1-only computation (voxel counts, the cheapest useful
score) and the naive all-pairs diameter (O(n^2) pixel-centre distances per slice) that the
convex-hull diameter replaces; the two diameters must agree.
"""

from __future__ import annotations

from lesscli.bench.timing import best_time

GRID_SHAPE = (26, 128, 128)
GRID_SPACING_MM = (0.9, 0.4774, 0.4774)


def _volumes(diameter_mm: float, seed: int):
    """Truth with one sphere of ``diameter_mm`` and a prediction shifted and with noisy boundary."""
    import numpy as np

    rng = np.random.default_rng(seed)
    spacing = np.array(GRID_SPACING_MM)
    origin = -np.array([(GRID_SHAPE[0] - 1) * spacing[0], (GRID_SHAPE[1] - 1) / 2 * spacing[1],
                        (GRID_SHAPE[2] - 1) / 2 * spacing[2]])
    z, y, x = np.meshgrid(*(origin[a] + spacing[a] * np.arange(GRID_SHAPE[a]) for a in range(3)),
                          indexing="ij")
    truth = np.ones(GRID_SHAPE, np.uint8)
    r_mm = np.sqrt((z + 11.0) ** 2 + (y - 2.0) ** 2 + (x + 3.0) ** 2)
    truth[r_mm <= diameter_mm / 2] = 3
    pred = np.ones(GRID_SHAPE, np.uint8)
    r_pred = np.sqrt((z + 11.5) ** 2 + (y - 2.8) ** 2 + (x + 2.0) ** 2) + rng.normal(0, 0.3, GRID_SHAPE)
    pred[r_pred <= diameter_mm / 2 * 0.9] = 3
    return pred, truth, origin, spacing


def run_metrics(diameter_mm: float, repeat: int, seed: int) -> list[dict]:
    """Four rows: full scoring vs F1 only, convex-hull diameter vs all pairs (seconds, best of ``repeat``)."""
    from lesscli.metrics.masks import all_pairs_diameter_mm, confusion, f1_from
    from lesscli.metrics.masks import diameter_mm as hull_diameter
    from lesscli.metrics.volume import score_labels

    pred, truth, origin, spacing = _volumes(diameter_mm, seed)
    t_full, row = best_time(lambda: score_labels(pred, truth, origin, spacing), repeat)
    t_f1, f1 = best_time(lambda: f1_from(*confusion(pred == 3, truth == 3)), repeat)
    t_hull, d_hull = best_time(lambda: hull_diameter(truth == 3, spacing), repeat)
    t_pairs, d_pairs = best_time(lambda: all_pairs_diameter_mm(truth == 3, spacing), max(1, repeat // 2))
    common = {"shape": "x".join(map(str, GRID_SHAPE)), "inclusion_diameter_mm": diameter_mm, "repeat": repeat}
    return [
        {"bench": "metrics", "case": "score_volume (3D + 2D, all metrics)", **common, "seconds": t_full,
         "ratio_vs_f1_only": t_full / t_f1, "f1_3d": row["f1_3d"],
         "diameter_true_mm_3d": row["diameter_true_mm_3d"]},
        {"bench": "metrics", "case": "baseline: F1 only (voxel counts)", **common, "seconds": t_f1,
         "ratio_vs_f1_only": 1.0, "f1_3d": f1},
        {"bench": "metrics", "case": "diameter, convex hull of row extremes", **common, "seconds": t_hull,
         "speedup_vs_all_pairs": t_pairs / t_hull, "diameter_mm": d_hull},
        {"bench": "metrics", "case": "baseline: diameter, all pairs per slice", **common, "seconds": t_pairs,
         "speedup_vs_all_pairs": 1.0, "diameter_mm": d_pairs,
         "diameters_agree": abs(d_hull - d_pairs) < 1e-9},
    ]
