"""``less bench guide``: closed-loop palpation with the simulator; F1 against the number of touches.

Each held-out test phantom is poked by the simulator on a dense pool of candidate touches (a jittered
3 mm grid, subsampled 1:50 like the training data), and a strategy decides which pool touch comes next
(:meth:`Loop._plan`): ``guided`` (``lesscli.infer.guide`` on the streamed image, covering the class
entropy), ``guided-inclusion`` (the inclusion-vs-rest entropy), ``raster`` (the paper's row-by-row robot
scan, fitted to the touch budget) or ``random``. All start from the same ``--start`` random touches; the
image is updated incrementally (``lesscli.infer.stream``) and its inclusion F1 scored every
``--eval-every`` touches. The summary row (:func:`summary_row`) tells how many touches each strategy
needs to match the raster scan's final F1. Without ``--model`` a small 2D model is trained first on
simulated poke data of other inserts (minutes; cached in ``--work-dir``).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

LOG = logging.getLogger("less")
TEST_INSERTS = ("St12C9", "St14D13", "St16C5")
POOL_SPACING_MM = 3.0
POOL_MARGIN_MM = 3.0
SUBSAMPLE_EVERY = 50
GUIDED = {"guided": "entropy", "guided-inclusion": "inclusion"}     # strategy -> guide score
STRATEGIES = (*GUIDED, "raster", "random")
F1_TOL = 1e-12                 # F1 equal to the target up to rounding counts as reaching it


def _scene(names, orientations, n_traj: int, spacing_mm: float, seed: int, name: str):
    from lesscli.sim.scene import parse_scene

    doc = {"name": name, "seed": seed, "phantoms": {"set": "single", "names": list(names),
                                                     "orientations": list(orientations)},
           "sensor": {"layout": "xela"}, "contact": {"tier": "winkler"},
           "motion": {"kind": "poke", "n_traj": n_traj, "spacing_mm": spacing_mm,
                      "margin_mm": POOL_MARGIN_MM}}
    return parse_scene(doc, where=f"<bench guide {name}>")


def simulate_set(names, orientations, n_traj: int, spacing_mm: float, seed: int, name: str):
    """Simulate poke scans and subsample them 1:50 (the training data's rate)."""
    from lesscli.data.ops import subsample
    from lesscli.sim.simulate import simulate

    return subsample(simulate(_scene(names, orientations, n_traj, spacing_mm, seed, name)),
                     every=SUBSAMPLE_EVERY)


def train_model(work: str, quick: bool, seed: int) -> str:
    """Train (or reuse) a small 2D imaging model on held-in inserts; returns the checkpoint path.

    The demo's recipe (``less-taxel``, d_z 16, K = K' = 8; decoder width 16 on 16-pixel patches, class
    weights frequency^-0.5), with fewer epochs when ``quick``."""
    from lesscli.phantom.catalogue import single
    from lesscli.train.config import LoopConfig, ModelConfig, PretrainConfig, SSLConfig
    from lesscli.train.image_fit import ImageFitConfig, ImageModelConfig, LossConfig, fit_imager
    from lesscli.train.pretrain import pretrain

    path = os.path.join(work, f"imager_{'quick' if quick else 'full'}_s{seed}.pt")
    if os.path.exists(path):
        return path
    os.makedirs(work, exist_ok=True)
    names = [p.name for p in single() if p.name not in TEST_INSERTS][::2 if quick else 1][:4 if quick else 18]
    orientations = (0, 4) if quick else (0, 2, 4, 6)
    LOG.warning("bench guide: simulating %d training scans", len(names) * len(orientations))
    train = simulate_set(names, orientations, 100, 6.0, seed + 1000, "guide-train")
    ssl_epochs, fit_epochs = (4, 20) if quick else (8, 40)
    rep = os.path.join(work, f"rep_{'quick' if quick else 'full'}_s{seed}.pt")
    LOG.warning("bench guide: pretraining (%d epochs)", ssl_epochs)
    pretrain(train, None, PretrainConfig(model=ModelConfig(name="less-taxel", dim=16), ssl=SSLConfig(8, 8),
                                         train=LoopConfig(epochs=ssl_epochs, lr=3e-3, batch_size=4, seed=seed,
                                                          device="cpu")), rep)
    LOG.warning("bench guide: fitting the 2D image decoder (%d epochs)", fit_epochs)
    fit_imager(train, None, rep, ImageFitConfig(image=ImageModelConfig(dim=2, width=16, patch_px=16),
                                                train=LoopConfig(epochs=fit_epochs, lr=1e-2, batch_size=4,
                                                                 seed=seed, device="cpu"),
                                                loss=LossConfig(alpha_power=0.5)), path)
    return path


def raster_points(budget: int, width_mm: float = 60.0, margin_mm: float = POOL_MARGIN_MM):
    """(n, 2) row-by-row grid points inside the shrunk octagon, spacing chosen so n is close to ``budget``."""
    import numpy as np

    from lesscli.phantom.geometry import Phantom

    inner = Phantom(name="outline", width_mm=width_mm - 2 * margin_mm)
    best = None
    for spacing in np.linspace(2.0, 20.0, 181):
        ticks = np.arange(-np.floor(30 / spacing), np.floor(30 / spacing) + 1) * spacing
        gx, gy = np.meshgrid(ticks, ticks)
        pts = np.stack([gx.ravel(), gy.ravel()], 1)
        pts = pts[inner.inside_outline(pts[:, 0], pts[:, 1])]
        if best is None or abs(len(pts) - budget) < abs(len(best) - budget):
            best = pts
    return best


class Loop:
    """One phantom's touch pool and imaging state for the closed loop.

    Args:
        imager, ckpt: the imaging model and its checkpoint.
        pool: a ScanSet with one scan (one trajectory per candidate touch).
    """

    def __init__(self, imager, ckpt: dict, pool) -> None:
        import numpy as np

        from lesscli.data.image_labels import AUTO_SLICE
        from lesscli.infer.predict import scan_grid

        cfg = ckpt["config"]["image"]
        self.grid, self.truth = scan_grid(pool, 0, int(cfg["dim"]), int(cfg.get("slice", AUTO_SLICE)),
                                          imager.grid)
        self.imager, self.ckpt, self.pool = imager, ckpt, pool
        off = pool.traj_offsets
        self.spans = [(int(off[i]), int(off[i + 1])) for i in range(pool.n_traj)]
        self.xy = np.array([pool.pose[a:b, :2].mean(0) for a, b in self.spans])

    def nearest_unused(self, xy, used: set[int]) -> int:
        import numpy as np

        d2 = ((self.xy - np.asarray(xy)[None]) ** 2).sum(1)
        d2[list(used)] = np.inf
        return int(np.argmin(d2))

    def f1(self, stream) -> float:
        from lesscli.io.labels import INCLUSION
        from lesscli.io.predictions import labels_from_probs
        from lesscli.metrics.masks import confusion, f1_from

        labels = labels_from_probs(stream.probs())
        f1 = f1_from(*confusion(labels == INCLUSION, self.truth == INCLUSION))
        return 0.0 if f1 is None else float(f1)

    def run(self, strategy: str, start: list[int], budget: int, eval_every: int, batch: int,
            rng) -> list[tuple]:
        """[(touches, F1)] for one strategy, evaluated every ``eval_every`` touches and at the budget."""
        from lesscli.infer.stream import StreamingImager

        stream = StreamingImager(self.imager, self.ckpt["norm_stats"], self.grid, defer_decode=True)
        used: list[int] = []
        queue: list = []
        curve = []
        while len(used) < min(budget, len(self.spans)):
            if len(used) < len(start):
                j = start[len(used)]
            else:
                if not queue:
                    queue = self._plan(strategy, stream, budget - len(used), batch, rng)
                j = self.nearest_unused(queue.pop(0), set(used))
            a, b = self.spans[j]
            for i in range(a, b):
                stream.push(self.pool.pose[i], self.pool.force[i])
            used.append(j)
            if len(used) % eval_every == 0 or len(used) == budget:
                curve.append((len(used), self.f1(stream)))
        return curve

    def _plan(self, strategy: str, stream, left: int, batch: int, rng) -> list:
        """The next target x, y positions (mm) of a strategy: the guide's ``batch`` suggestions, the rest
        of a raster fitted to the ``left`` touches, or the pool in random order."""
        import numpy as np

        from lesscli.infer.guide import UNCERTAINTY, GuideOptions, octagon_mask, suggest_touches

        if strategy == "raster":
            return list(raster_points(left))
        if strategy == "random":
            return list(self.xy[rng.permutation(len(self.xy))])
        allowed = octagon_mask(self.grid, 60.0, POOL_MARGIN_MM)
        score = UNCERTAINTY[GUIDED[strategy]](stream.probs())
        rows = suggest_touches(score, self.grid, allowed, GuideOptions(k=batch), stream.radius_mm)
        return [np.array([r["x_mm"], r["y_mm"]]) for r in rows]


def touches_to_reach(curve: list[tuple], target: float) -> int | None:
    """First touch count from which the F1 stays at or above ``target`` (None if it never settles there)."""
    for i, (n, _) in enumerate(curve):
        if all(f >= target - F1_TOL for _, f in curve[i:]):
            return n
    return None


def first_reach(curve: list[tuple], target: float) -> int | None:
    """First touch count whose F1 is at or above ``target`` (None if never)."""
    return next((n for n, f in curve if f >= target - F1_TOL), None)


def mean_curves(curves: dict[str, list[list[tuple]]]) -> dict[str, list[tuple]]:
    """Average F1 over runs at each touch count (runs share their evaluation points)."""
    import numpy as np

    return {s: [(n, float(np.mean([c[i][1] for c in runs]))) for i, (n, _) in enumerate(runs[0])]
            for s, runs in curves.items()}


@dataclass(frozen=True)
class GuideBench:
    """Sizes of a closed-loop run.

    Attributes:
        budget: touches per run; start: random first touches shared by all strategies;
        seeds: runs per phantom; eval_every: touches between two scores; batch: guided touches per round;
        seed: base seed of the pools, the first touches and the random order.
    """

    budget: int
    start: int
    seeds: int
    eval_every: int
    batch: int
    seed: int


def run_guide(model_path: str, bench: GuideBench) -> tuple[list[dict], dict[str, list[tuple]]]:
    """Every strategy on every test phantom and seed with the imaging checkpoint at ``model_path``.

    Returns:
        records (one per strategy and evaluation point, then the summary) and strategy -> mean curve.
    """
    import numpy as np

    from lesscli.infer.predict import load_imager

    imager, ckpt = load_imager(model_path)
    curves: dict[str, list] = {s: [] for s in STRATEGIES}
    for r in range(bench.seeds):
        for name in TEST_INSERTS:
            pool = simulate_set([name], [0], 260, POOL_SPACING_MM, bench.seed + r, f"guide-pool-{name}")
            loop = Loop(imager, ckpt, pool)
            start = list(np.random.default_rng([bench.seed, r]).choice(pool.n_traj, bench.start,
                                                                       replace=False))
            for s in STRATEGIES:
                curves[s].append(loop.run(s, start, bench.budget, bench.eval_every, bench.batch,
                                          np.random.default_rng([bench.seed, r, 1])))
    means = mean_curves(curves)
    rows = [{"bench": "guide", "strategy": s, "touches": n, "f1": f} for s, c in means.items() for n, f in c]
    rows.append(summary_row(means, bench, model_path))
    return rows, means


def summary_row(means: dict[str, list[tuple]], bench: GuideBench, model_path: str) -> dict:
    """Touches each strategy needs to reach the raster strategy's final F1 (to stay at or above it, and to
    reach it first), and the mean F1 over the curve per strategy.

    Where raster ends no higher than the shared start (the model images nothing on these phantoms), every
    strategy "reaches" it at the start: the touch counts and the saving are None and ``note`` says why.
    """
    import numpy as np

    target, start_f1 = means["raster"][-1][1], means["raster"][0][1]
    gained = target > start_f1 + F1_TOL

    def reach(strategy: str, rule=touches_to_reach) -> int | None:
        return rule(means[strategy], target) if gained else None

    need = reach("guided")
    row = {"bench": "guide", "strategy": "summary", "raster_final_f1": target, "touch_budget": bench.budget,
           "guided_touches_to_raster_final": need, "random_touches_to_raster_final": reach("random"),
           "guided_saving": None if need is None else 1.0 - need / bench.budget,
           "guided_first_reaches_raster_final": reach("guided", first_reach),
           "guided_inclusion_touches_to_raster_final": reach("guided-inclusion"),
           **{f"mean_f1_{k}": float(np.mean([f for _, f in c])) for k, c in means.items()},
           "phantoms": len(TEST_INSERTS), "seeds": bench.seeds, "model": model_path}
    if not gained:
        row["note"] = (f"raster ends at F1 {target:.3f}, no higher than after the shared start touches "
                       f"({start_f1:.3f}): nothing to reach, no touch counts compared")
    return row
