"""3D micro inclusion F1 of predictions whose inclusion regions are redrawn as balls (the phantoms' shape).

For each `less image predict` output given, every face-connected inclusion region of the label volume
is replaced by the ball of its volume at its centroid: always, or only where the region is round (at
least GATE of its voxels inside that ball). Prints the micro F1 (pooled over scans) of the labels as
predicted and under each rule. An analysis of predictions already made (no model is run); scored
against the truth stored in the predictions.

    python examples/ball_rule.py work/accuracy/pred_img_less-taxel_s0_on_single.npz ...
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import ndimage

INCLUSION = 3
GATES = (0.0, 0.6, 0.7, 0.8, 0.9)      # 0: every region


def _regions(pred: np.ndarray, spacing: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Each inclusion region, the ball of its volume at its centroid, and the share of it inside that ball."""
    regions, n = ndimage.label(pred)
    centres_mm = np.indices(pred.shape).reshape(3, -1).T * spacing
    out = []
    for i in range(1, n + 1):
        region = regions == i
        centre = np.asarray(ndimage.center_of_mass(region)) * spacing
        radius = (3 * region.sum() * np.prod(spacing) / (4 * np.pi)) ** (1 / 3)
        ball = (np.linalg.norm(centres_mm - centre, axis=1) <= radius).reshape(pred.shape)
        out.append((region, ball, (region & ball).sum() / region.sum()))
    return out


def micro_f1(path: str) -> dict:
    d = np.load(path, allow_pickle=True)
    counts = {rule: np.zeros(3) for rule in ("as predicted", *GATES)}
    offset = 0
    for shape, spacing in zip(d["probs_shape"], d["spacing_mm"]):
        size = int(np.prod(shape[1:]))
        pred = d["label_data"][offset:offset + size].reshape(shape[1:]) == INCLUSION
        truth = d["truth_data"][offset:offset + size].reshape(shape[1:]) == INCLUSION
        offset += size
        regions = _regions(pred, spacing)
        for rule in counts:
            p = pred
            if rule != "as predicted":
                p = np.zeros(pred.shape, dtype=bool)
                for region, ball, inside in regions:
                    p |= ball if inside >= rule else region
            counts[rule] += [(p & truth).sum(), (p & ~truth).sum(), (~p & truth).sum()]
    return {rule: 2 * tp / max(2 * tp + fp + fn, 1) for rule, (tp, fp, fn) in counts.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("preds", nargs="+", help="prediction files (`less image predict` outputs with truth)")
    args = parser.parse_args()
    print("| file | as predicted | "
          + " | ".join("every region" if g == 0 else f"round >= {g:g}" for g in GATES)
          + " |")
    print("|---" * (len(GATES) + 2) + "|")
    for path in args.preds:
        f1 = micro_f1(path)
        print(f"| {path} | " + " | ".join(f"{v:.3f}" for v in f1.values()) + " |")


if __name__ == "__main__":
    main()
