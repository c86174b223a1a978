"""``less image fit --model forcemap``: calibrate the classical force-map imager, write it as a checkpoint.

The checkpoint is a normal ``less.checkpoint`` (``torch.load(weights_only=True)``) with an empty model
state and ``config = {"model": "forcemap", "forcemap": <Calibration as a dict>, "image": {"dim",
"slice"}, "grid": <first training target grid>, "data": <the training scans' data signature>}``; ``less image
predict`` recognises it by ``config["model"]`` (:func:`lesscli.infer.predict.predict_file`).
"""

from __future__ import annotations

import time
from dataclasses import asdict

from lesscli.data.compat import signature
from lesscli.data.image_labels import AUTO_SLICE, grid_of, target_volume
from lesscli.errors import DataError
from lesscli.infer import forcemap
from lesscli.io.checkpoint import save_checkpoint
from lesscli.io.scans import ScanSet
from lesscli.models.imager import grid_to_dict


def fit_forcemap(scans: ScanSet, output: str, dim: int = 3, slice_index: int | None = None,
                 name: str = "scan set", history: list | None = None,
                 sigmas_mm: tuple[float, ...] = forcemap.SIGMAS_MM,
                 grid_mm: float = forcemap.GRID_MM) -> dict:
    """Calibrate on ``scans`` (every scan needs a label volume), save to ``output``; returns a summary record.

    ``dim`` and ``slice_index`` (None: through the inclusion centre) choose the targets as ``image fit`` does;
    ``sigmas_mm`` and ``grid_mm`` are the smoothing widths tried and the map's cell (``less bench tradeoff``).
    """
    t0 = time.perf_counter()
    slice_index = AUTO_SLICE if slice_index is None else int(slice_index)
    labels = [scans.label_of(s) for s in range(scans.n_scans)]
    missing = [s for s, v in enumerate(labels) if v is None]
    if not labels:
        raise DataError(f"{name}: no scans to calibrate on")
    if missing:
        raise DataError(f"{name}: scan {missing[0]} ({scans.scan_insert[missing[0]]}) has no label volume; "
                        "calibration needs labels for every training scan")
    taxel_xy = forcemap.taxel_layout(scans.meta, name)
    targets = [target_volume(v, dim, slice_index) for v in labels]
    touches = [forcemap.scan_touches(scans, s, taxel_xy) for s in range(scans.n_scans)]
    cal, f1 = forcemap.calibrate(touches, labels, targets, name, sigmas_mm, grid_mm)
    config = {"model": forcemap.MODEL, "forcemap": asdict(cal), "image": {"dim": dim, "slice": slice_index},
              "grid": grid_to_dict(grid_of(targets[0])), "data": signature(scans)}
    save_checkpoint(output, {}, config, {}, history or [], {"train_inclusion_f1": f1})
    shown = {k: v for k, v in asdict(cal).items() if not k.startswith("prior")}
    return {"output": output, "model": forcemap.MODEL, "dim": dim, "scans": scans.n_scans, **shown,
            "train_inclusion_f1": round(f1, 4), "seconds": round(time.perf_counter() - t0, 2)}
