"""How much of an inclusion's size do the touches of a scene hold? A ceiling for any imager.

For every scan with one inclusion, the classical force map (``lesscli.infer.forcemap``: stiffness per
taxel at each poke's deepest step, flat-fielded, quadratic trend removed) is sampled on a window of
cells around the inclusion's TRUE centre (default 21 x 21 at 1 mm), with its radial profile in 1 mm
rings out to 10 mm (raw and divided by its peak, a scale-free shape). Regressors fitted on the training
scans map these to the volume-equivalent diameter and are scored on the test scans. Then spheres are drawn
at each test inclusion's TRUE 3D centroid with (a) its true diameter, (b) the regressed one, (c) the
training mean, and (d) the true one moved 1.5 mm sideways, and the 3D micro F1 against the label volumes
is printed: what an imager that already knew where the inclusion is would score with these touches' size.

    python examples/size_ceiling.py work/accuracy/split/train.npz work/accuracy/single.npz
    python examples/size_ceiling.py ... --cells 7 --pitch-mm 2.5     # the window of a particle's map

Needs scikit-learn (the test extra).
"""

from __future__ import annotations

import argparse

import numpy as np
from sklearn.ensemble import GradientBoostingRegressor
from sklearn.linear_model import RidgeCV

from lesscli.infer.forcemap import (
    GRID_MM,
    inclusions,
    scan_touches,
    signed_distance_mm,
    stiffness_map,
    taxel_layout,
)
from lesscli.io.scans import load_scans

RINGS = 10                      # 1 mm rings of the radial profile


def features(path: str, sigma_mm: float, offsets_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    """(n, f) map features around each single inclusion's true centre, (n,) diameters, [(scan, label)]."""
    scans = load_scans(path)
    layout = taxel_layout(scans.meta, path)
    radius = np.hypot(*np.meshgrid(offsets_mm, offsets_mm))
    rings = [(radius >= k) & (radius < k + 1) for k in range(RINGS)]
    rings = [r for r in rings if r.any()]
    x_rows, diameters, where = [], [], []
    for s in range(scans.n_scans):
        label = scans.labels[scans.scan_label[s]]
        centres, diam = inclusions(label)
        if len(centres) != 1:
            continue
        _, cy, cx = centres[0]
        fmap = stiffness_map(scan_touches(scans, s, layout), sigma_mm)
        gx, gy = np.meshgrid(cx + offsets_mm, cy + offsets_mm)
        ix = np.round((gx - fmap.origin_xy_mm[0]) / GRID_MM).astype(int)
        iy = np.round((gy - fmap.origin_xy_mm[1]) / GRID_MM).astype(int)
        ok = (ix >= 0) & (iy >= 0) & (ix < fmap.residual.shape[1]) & (iy < fmap.residual.shape[0])
        patch = np.zeros(gx.shape)
        patch[ok] = fmap.residual[iy[ok], ix[ok]] / fmap.spread
        profile = np.array([patch[r].mean() for r in rings])
        peak = max(profile[:2].max(), 1e-9)
        x_rows.append(np.concatenate([patch.ravel(), profile, profile / peak,
                                      [peak, (profile / peak > 0.5).sum()]]))
        diameters.append(diam[0])
        where.append((s, label))
    return np.array(x_rows), np.array(diameters), where


def micro_f1(where: list, centres_dx_mm: float, diameters: np.ndarray) -> float:
    """3D micro F1 of spheres at each test inclusion's true centroid (moved by ``centres_dx_mm`` in x)."""
    tp = fp = fn = 0
    for (_, label), d in zip(where, diameters):
        (cz, cy, cx), = inclusions(label)[0]
        pred = signed_distance_mm(np.array([[cx + centres_dx_mm, cy, cz, d]]), label.shape, label.origin_mm,
                                  label.spacing_mm) <= 0
        truth = label.data == 3
        tp, fp, fn = tp + (pred & truth).sum(), fp + (pred & ~truth).sum(), fn + (~pred & truth).sum()
    return 2 * tp / (2 * tp + fp + fn)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("train")
    ap.add_argument("test")
    ap.add_argument("--sigma-mm", type=float, default=1.0, help="smoothing of the force map (mm)")
    ap.add_argument("--cells", type=int, default=21, help="window side in cells (odd)")
    ap.add_argument("--pitch-mm", type=float, default=1.0, help="window cell pitch (mm)")
    a = ap.parse_args()
    offsets = (np.arange(a.cells) - (a.cells - 1) / 2) * a.pitch_mm
    x_train, d_train, _ = features(a.train, a.sigma_mm, offsets)
    x_test, d_test, where = features(a.test, a.sigma_mm, offsets)
    print(f"{len(d_train)} training and {len(d_test)} test inclusions; test diameter SD {d_test.std():.2f} "
          "mm")
    print("| diameter from | R^2 | mean abs error (mm) | 3D micro F1, sphere at the true centroid |")
    print("|---|---|---|---|")
    print(f"| truth | 1 | 0 | {micro_f1(where, 0.0, d_test):.3f} |")
    print(f"| truth, centre moved 1.5 mm | 1 | 0 | {micro_f1(where, 1.5, d_test):.3f} |")
    for name, model in (("ridge on the map", RidgeCV(alphas=np.logspace(-2, 3, 12))),
                        ("gradient boosting on the map", GradientBoostingRegressor(
                            n_estimators=200, max_depth=2, subsample=0.8, random_state=0))):
        pred = model.fit(x_train, d_train).predict(x_test)
        r2 = 1 - ((pred - d_test) ** 2).sum() / ((d_test - d_test.mean()) ** 2).sum()
        print(f"| {name} | {r2:.2f} | {np.abs(pred - d_test).mean():.2f} | {micro_f1(where, 0.0, pred):.3f} "
              "|")
    mean = np.full(len(d_test), d_train.mean())
    r2 = 1 - ((mean - d_test) ** 2).sum() / ((d_test - d_test.mean()) ** 2).sum()
    print(f"| training mean | {r2:.2f} | {np.abs(mean - d_test).mean():.2f} | "
          f"{micro_f1(where, 0.0, mean):.3f} |")


if __name__ == "__main__":
    main()
