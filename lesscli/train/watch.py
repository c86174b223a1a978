"""Watching a training run: the epoch bar, optional batch bars, per-epoch scalars for TensorBoard.

:class:`Watch` tells :func:`lesscli.train.loop.fit` how a run is shown. The epoch bar has one tick
per epoch (so tqdm's ETA is the time left for the run) and shows the current training loss and the
best validation value so far: the best validation score (imaging F1) when the run selects by one,
else the best validation loss (training loss without validation). Batch bars (one per epoch, cleared
after it) are shown only when asked for (``-v``).

``--tensorboard DIR`` writes every number of each epoch record (the keys of ``<stem>.log.jsonl``:
``train_loss``, ``val_loss``, ``val_score``, ``val_baseline_mse``, ``lr``) as a scalar of that name
at step = epoch, with ``torch.utils.tensorboard``, which needs the ``tensorboard`` package (the
optional extra ``pip install 'less-tactile[tensorboard]'``).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from lesscli.errors import LessError

NOT_SCALARS = {"epoch", "step", "best", "seconds"}   # record keys that are bookkeeping, not curves


def no_bar(iterable=None, **_kwargs):
    """A progress factory that shows nothing."""
    return iterable


@dataclass
class Watch:
    """How a run is shown: ``epochs`` wraps the epoch range (a progress factory, tqdm-like), ``batches``
    wraps each epoch's loader (None: no batch bars), ``on_epoch`` callables get each epoch record (rank 0)."""

    epochs: Callable = no_bar
    batches: Callable | None = None
    on_epoch: list[Callable[[dict], None]] = field(default_factory=list)


def bar_postfix(record: dict, best: dict) -> dict:
    """What the epoch bar shows after ``record``: its training loss and the best validation value.

    ``best`` is the record of the best epoch so far.
    """
    shown = {"loss": f"{record['train_loss']:.4g}"}
    if best.get("val_score") is not None:
        shown["best_val_f1"] = f"{best['val_score']:.3f}"
    elif best.get("val_loss") is not None:
        shown["best_val_loss"] = f"{best['val_loss']:.4g}"
    else:
        shown["best_loss"] = f"{best['train_loss']:.4g}"
    return shown


def require_tensorboard(logdir: str) -> None:
    """Raise LessError (one line, how to fix) when ``torch.utils.tensorboard`` cannot be used."""
    try:
        importlib.import_module("tensorboard")
        importlib.import_module("torch.utils.tensorboard")
    except ImportError as exc:
        raise LessError(f"--tensorboard {logdir}: the 'tensorboard' package is not installed ({exc}); "
                        "pip install 'less-tactile[tensorboard]' or leave the option out") from None


class TensorBoardScalars:
    """Per-epoch callback writing the record's numbers as scalars into an event file under ``logdir``."""

    def __init__(self, logdir: str) -> None:
        require_tensorboard(logdir)
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(log_dir=logdir)

    def __call__(self, record: dict) -> None:
        for key, value in record.items():
            if key in NOT_SCALARS or isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            if math.isfinite(value):
                self.writer.add_scalar(key, value, record["epoch"])
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
