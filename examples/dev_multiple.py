"""A development set of multiple-inclusion inserts, drawn apart from the ``multiple`` catalogue.

Choices between LESS variants that are about multiple inclusions (the compositional claim) are made on
these inserts, so the catalogue's ``multiple`` set stays a test set that no choice has looked at. Same
construction as the catalogue (spheres at the manufacturing depth, each on its own pillar, catalogue
materials) with other counts, sizes, directions and places, drawn from a fixed seed:

    python examples/dev_multiple.py > examples/scenes/dev-multiple.json

(a phantom-set file as ``less phantom`` writes them: a JSON list of phantom specs). The headline run
simulates it with its scene as the ``dev`` set (``make -C examples accuracy``: ``work/accuracy/dev.npz``).
"""

from __future__ import annotations

import json
import math

import numpy as np

from lesscli.phantom.catalogue import hanging, inclusion_depth_mm
from lesscli.phantom.geometry import Phantom, Sphere

SEED = 2027
REACH_MM = 19.0          # every sphere's centre within this distance of the insert's centre


def _spheres(kind: str, rng: np.random.Generator) -> list[Sphere]:
    count = int(rng.integers(2, 5)) if kind != "separate" else int(rng.integers(2, 4))
    while True:
        if kind == "chain":                          # touching spheres on a line
            d = float(rng.choice([8.0, 10.0, 12.0]))
            ang, step = rng.uniform(0, 2 * math.pi), d * rng.uniform(0.7, 0.9)
            x0, y0 = rng.uniform(-8, 8, 2)
            xy = [(x0 + i * step * math.cos(ang), y0 + i * step * math.sin(ang)) for i in range(count)]
            ds = [d] * count
        elif kind == "curve":                        # touching spheres on an arc about the centre
            d = float(rng.choice([8.0, 10.0]))
            radius = rng.uniform(11, 16)
            a0, da = rng.uniform(0, 2 * math.pi), d * rng.uniform(0.75, 0.95) / radius
            xy = [(radius * math.cos(a0 + i * da), radius * math.sin(a0 + i * da)) for i in range(count)]
            ds = [d] * count
        else:                                        # apart from one another
            ds = [float(v) for v in rng.choice([8.0, 10.0, 12.0, 14.0], count)]
            xy = [tuple(rng.uniform(-16, 16, 2)) for _ in range(count)]
            gaps = [math.dist(xy[i], xy[j]) - (ds[i] + ds[j]) / 2 for i in range(count) for j in range(i)]
            if min(gaps) < 4.0:
                continue
        if all(math.hypot(x, y) <= REACH_MM for x, y in xy):
            return [Sphere((round(x, 3), round(y, 3), inclusion_depth_mm(d / 2)), d / 2) for (x, y),
                    d in zip(xy, ds)]


def dev_multiple(seed: int = SEED) -> list[Phantom]:
    """Eight inserts: three chains, two curves, three with separate inclusions."""
    rng = np.random.default_rng(seed)
    out = []
    for i, kind in enumerate(["chain", "curve", "separate", "chain", "separate", "curve", "chain",
                              "separate"]):
        inclusions, pillars = hanging(_spheres(kind, rng))
        out.append(Phantom(f"Dev{i}{kind[:2].capitalize()}{len(inclusions)}", inclusions=inclusions,
                           pillars=pillars))
    return out


def main() -> None:
    print(json.dumps([phantom.to_dict() for phantom in dev_multiple()], indent=1))


if __name__ == "__main__":
    main()
