"""A generic training loop: Adam, cosine schedule, best-by-validation checkpoints, resume, NaN guard.

Usage (any model whose loss is computed through its ``forward``)::

    def loss_fn(model, batch, generator):        # model may be DDP-wrapped: call model(...) once
        return model(batch, generator)

    result = fit(model, loss_fn, train_set, val_set, cfg, collate_fn=collate, output="rep.pt",
                 config=resolved_config_dict, norm_stats=stats, env=distributed.setup(cfg.device))

Files (rank 0 only): ``output`` holds the best model so far and is rewritten with the full history at
the end; ``<stem>.last.pt`` holds the latest epoch with optimizer and schedule state for ``resume=True``;
``<stem>.log.jsonl`` gets one JSON line per epoch (see :func:`fit`).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import nn

from lesscli.errors import TrainingError
from lesscli.io.checkpoint import load_checkpoint, save_checkpoint
from lesscli.train import distributed
from lesscli.train.config import LoopConfig
from lesscli.train.watch import Watch, bar_postfix

LossFn = Callable[[nn.Module, object, torch.Generator], torch.Tensor]
# val_fn(model, loader, device) -> (mean loss, score or None): one pass over the validation set
ValFn = Callable[[nn.Module, object, torch.device], tuple[float, float | None]]
EVAL_SEED = 20_251_120          # validation draws use a fixed stream so epochs are comparable
CLOCK_KEYS = ("seconds",)       # epoch-record keys measured by the clock: in the log, never in a checkpoint
RESUME_FREE = {"epochs", "device", "num_workers"}   # settings a resumed run may change


def _stream_seed(seed: int, epoch: int, stream: int) -> int:
    """A 63-bit seed for one (run seed, epoch, stream) triple."""
    return int.from_bytes(hashlib.blake2b(f"{seed}/{epoch}/{stream}".encode(), digest_size=8).digest(),
                          "big") >> 1


def timeless(history: list[dict]) -> list[dict]:
    """``history`` without the wall-clock figures (:data:`CLOCK_KEYS`), as checkpoints store it: a rerun
    that computes the same weights writes the same checkpoint bytes (the log keeps the timings)."""
    return [{k: v for k, v in h.items() if k not in CLOCK_KEYS} for h in history]


def _strip(config):
    """``config`` without the settings a resumed run may change."""
    if isinstance(config, dict):
        return {k: _strip(v) for k, v in config.items() if k not in RESUME_FREE}
    return config


@dataclass
class FitResult:
    """What :func:`fit` did: per-epoch records, the best epoch, its loss and its validation score."""

    history: list[dict] = field(default_factory=list)
    best_epoch: int = -1
    best_loss: float = math.inf
    best_score: float | None = None
    best_state: dict | None = None

    def criterion(self) -> tuple[float, float]:
        """What a better epoch must beat (see :func:`rank`)."""
        return rank(self.best_score, self.best_loss)


def rank(score: float | None, loss: float) -> tuple[float, float]:
    """Epoch order, lower is better, lexicographically: (-score, loss); no score counts as -inf."""
    return (math.inf if score is None else -score, loss)


def data_identity(scans, norm_stats: dict, name: str) -> dict:
    """What ``--resume`` must find unchanged: the training data's content and its normalisation."""
    h = hashlib.sha1(scans.fingerprint().encode())
    h.update(json.dumps(norm_stats, sort_keys=True).encode())
    return {"name": name, "fingerprint": h.hexdigest()[:16]}


def side_paths(output: str) -> tuple[str, str]:
    """(last-epoch checkpoint, JSON-lines log) beside ``output``."""
    stem = output.removesuffix(".pt")
    return f"{stem}.last.pt", f"{stem}.log.jsonl"


def cosine_factor(step: int, total: int, min_ratio: float) -> float:
    """Learning-rate multiplier: 1 at step 0, ``min_ratio`` at ``total``."""
    progress = min(1.0, step / max(1, total))
    return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def _loader(dataset, cfg: LoopConfig, collate_fn, env: distributed.DistEnv, shuffle: bool,
            generator: torch.Generator):
    from torch.utils.data import DataLoader, DistributedSampler, RandomSampler, SequentialSampler

    if env.distributed:
        sampler = DistributedSampler(dataset, num_replicas=env.world_size, rank=env.rank, shuffle=shuffle,
                                     seed=cfg.seed)
    else:
        sampler = RandomSampler(dataset, generator=generator) if shuffle else SequentialSampler(dataset)
    return DataLoader(dataset, batch_size=cfg.batch_size, sampler=sampler, collate_fn=collate_fn,
                      num_workers=cfg.num_workers)


def loss_only(loss_fn: LossFn) -> ValFn:
    """The default validation: mean ``loss_fn`` over the loader with the fixed evaluation stream, no score."""
    def val_fn(model: nn.Module, loader, device: torch.device) -> tuple[float, None]:
        gen = torch.Generator().manual_seed(EVAL_SEED)
        total, n = 0.0, 0
        for batch in loader:
            total += float(loss_fn(model, batch.to(device), gen)) * batch.size
            n += batch.size
        return total / max(1, n), None
    return val_fn


def validate(val_fn: ValFn, model: nn.Module, loader, device: torch.device) -> tuple[float, float | None]:
    """``val_fn`` with the model in evaluation mode and without gradients."""
    was_training = model.training
    model.eval()
    with torch.no_grad():
        loss, score = val_fn(model, loader, device)
    model.train(was_training)
    return float(loss), None if score is None else float(score)


class _Trainer:
    """State of one :func:`fit` call (kept in an object so each step stays short)."""

    def __init__(self, model, loss_fn, cfg, env, output, ckpt_info, watch: Watch):
        self.raw = model.to(env.device)
        self.model = distributed.wrap(self.raw, env)
        self.loss_fn, self.cfg, self.env, self.output = loss_fn, cfg, env, output
        self.ckpt_info, self.watch = ckpt_info, watch
        params = [p for p in self.raw.parameters() if p.requires_grad]
        self.params = params
        # a model may give its parts their own learning rates (an imager's trained encoder)
        groups = self.raw.param_groups(cfg.lr) if params and hasattr(self.raw, "param_groups") else params
        self.opt = torch.optim.Adam(groups, lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.total_steps = 1
        self.sched = None
        self.data_gen = torch.Generator()
        self.loss_gen = torch.Generator()
        self.result = FitResult()
        self.start_epoch = 0
        self.step = 0
        self.last_path, self.log_path = side_paths(output) if output != "-" else (None, None)
        self.saved_any = False

    def make_schedule(self, steps_per_epoch: int) -> None:
        self.total_steps = max(1, steps_per_epoch * self.cfg.epochs)
        def factor(step: int) -> float:
            return cosine_factor(step, self.total_steps, self.cfg.min_lr_ratio)

        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, factor)

    def resume(self) -> None:
        if not self.last_path or not os.path.exists(self.last_path):
            raise TrainingError(f"{self.last_path or self.output}: nothing to resume from (no last-epoch "
                                "checkpoint)")
        ckpt = load_checkpoint(self.last_path, map_location="cpu")
        if _strip(ckpt["config"]) != _strip(self.ckpt_info["config"]):
            raise TrainingError(f"{self.last_path}: its config differs from this run's; resume with the same "
                                "options")
        extra = ckpt["extra"]
        before, now = extra.get("data"), self.ckpt_info.get("data")
        if before and now and before.get("fingerprint") != now.get("fingerprint"):
            raise TrainingError(f"{self.last_path}: was trained on {before.get('name')} (data fingerprint "
                                f"{before.get('fingerprint')}), but this run's {now['name']} differs "
                                f"({now['fingerprint']}, data or normalisation); resume with the same data "
                                "or start afresh without --resume")
        self.raw.load_state_dict(ckpt["model_state"])
        self.opt.load_state_dict(extra["optimizer"])
        self.sched.load_state_dict(extra["scheduler"])
        self.start_epoch, self.step = int(extra["epoch"]) + 1, int(extra["step"])
        self.result.history = [h for h in ckpt["history"] if "epoch" in h]
        self.result.best_epoch, self.result.best_loss = int(extra["best_epoch"]), float(extra["best_loss"])
        self.result.best_score = extra.get("best_score")
        if os.path.exists(self.output):
            self.result.best_state = load_checkpoint(self.output)["model_state"]
            self.saved_any = True

    def train_step(self, batch, epoch: int, index: int) -> float:
        batch = batch.to(self.env.device)
        loss = self.loss_fn(self.model, batch, self.loss_gen)
        value = distributed.mean_across(loss.detach().reshape(1), self.env)
        self.guard(float(value), "loss", epoch, index)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        clip = self.cfg.grad_clip_norm if self.cfg.grad_clip_norm > 0 else math.inf
        norm = torch.nn.utils.clip_grad_norm_(self.params, clip) if self.params else torch.zeros(())
        self.guard(float(norm), "gradient norm", epoch, index)
        self.opt.step()
        self.sched.step()
        self.step += 1
        return float(value)

    def guard(self, value: float, what: str, epoch: int, index: int) -> None:
        if math.isfinite(value):
            return
        kept = (f"the last good checkpoint is kept at {self.output}" if self.saved_any
                else "no checkpoint was written yet")
        raise TrainingError(f"non-finite {what} ({value}) at epoch {epoch + 1}, batch {index + 1} "
                            f"(global step {self.step + 1}); {kept}. Lower --lr or check the data")

    def seed_epoch(self, epoch: int) -> None:
        """Random streams keyed by (seed, epoch, rank): a resumed run draws exactly as an uninterrupted
        one."""
        self.data_gen.manual_seed(_stream_seed(self.cfg.seed, epoch, 0))
        self.loss_gen.manual_seed(_stream_seed(self.cfg.seed, epoch, 1 + self.env.rank))

    def run_epoch(self, loader, epoch: int) -> float:
        self.seed_epoch(epoch)
        if hasattr(loader.sampler, "set_epoch"):
            loader.sampler.set_epoch(epoch)
        self.model.train()
        losses = []
        bar = self.watch.batches(loader, desc=f"epoch {epoch + 1}/{self.cfg.epochs}", leave=False) \
            if self.watch.batches else loader
        for i, batch in enumerate(bar):
            losses.append(self.train_step(batch, epoch, i))
            if hasattr(bar, "set_postfix"):
                bar.set_postfix(loss=f"{losses[-1]:.4g}")
        return sum(losses) / max(1, len(losses))

    def end_epoch(self, epoch: int, train_loss: float, val_loss: float | None, val_score: float | None,
                  seconds: float, extra: dict | None = None) -> dict:
        loss = val_loss if val_loss is not None else train_loss
        if val_score is not None and not math.isfinite(val_score):
            val_score = None                                     # undefined (NaN): never better
        improved = rank(val_score, loss) < self.result.criterion()
        if improved:
            self.result.best_loss, self.result.best_score, self.result.best_epoch = loss, val_score, epoch
            self.result.best_state = copy.deepcopy({k: v.detach().cpu() for k,
                                                    v in self.raw.state_dict().items()})
        record = {"epoch": epoch + 1, "step": self.step, "train_loss": train_loss, "val_loss": val_loss,
                  **({} if val_score is None else {"val_score": val_score}), **(extra or {}),
                  "lr": self.opt.param_groups[0]["lr"] if self.params else 0.0, "best": improved,
                  "seconds": round(seconds, 3)}
        self.result.history.append(record)
        if self.env.is_main:
            self._write(record, improved, epoch)
            for callback in self.watch.on_epoch:
                callback(record)
        distributed.barrier(self.env)
        return record

    def best_record(self, latest: dict) -> dict:
        """The epoch record of the best epoch so far (``latest`` when it is not in the history)."""
        return next((r for r in self.result.history if r["epoch"] == self.result.best_epoch + 1), latest)

    def _write(self, record: dict, improved: bool, epoch: int) -> None:
        info = self.ckpt_info
        if self.log_path:
            with open(self.log_path, "a") as fh:
                fh.write(json.dumps(record) + "\n")
        if self.output == "-":
            return
        if improved:
            save_checkpoint(self.output, self.result.best_state, info["config"], info["norm_stats"],
                            [*info.get("history", []), *timeless(self.result.history)], info.get("extra"))
            self.saved_any = True
        extra = {"optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(), "epoch": epoch,
                 "step": self.step, "best_epoch": self.result.best_epoch, "best_loss": self.result.best_loss,
                 "best_score": self.result.best_score, "data": info.get("data")}
        save_checkpoint(self.last_path, self.raw.state_dict(), info["config"], info["norm_stats"],
                        timeless(self.result.history), extra)

    def finish(self) -> None:
        """Rewrite the best checkpoint with the whole history (rank 0)."""
        info = self.ckpt_info
        if self.env.is_main and self.result.best_state is not None:
            save_checkpoint(self.output, self.result.best_state, info["config"], info["norm_stats"],
                            [*info.get("history", []), *timeless(self.result.history)],
                            {**(info.get("extra") or {}), "best_epoch": self.result.best_epoch + 1,
                             "best_loss": self.result.best_loss})
        distributed.barrier(self.env)


def fit(model: nn.Module, loss_fn: LossFn, train_set, val_set, cfg: LoopConfig, *, collate_fn, output: str,
        config: dict, norm_stats: dict, env: distributed.DistEnv | None = None, resume: bool = False,
        history: list | None = None, extra: dict | None = None, watch: Watch | None = None,
        val_fn: ValFn | None = None, record_extra: dict | None = None, data: dict | None = None) -> FitResult:
    """Train ``model`` by minimising ``loss_fn`` and keep the best checkpoint.

    The best is by validation loss, or by a validation score such as the imaging F1 with ties broken by
    the loss; by training loss when there is no validation set. Random streams are keyed by seed, epoch
    and rank, so a resumed run draws as an uninterrupted one. The log's lines carry each epoch's
    wall-clock ``seconds``, which the checkpoints leave out (:func:`timeless`). Parameters with
    ``requires_grad=False`` (a frozen representation) are not optimised.

    Args:
        model: the module to train (moved to ``env.device``; wrapped in DDP when distributed).
        loss_fn: ``loss_fn(model, batch, generator) -> scalar``; must call ``model(...)`` (its forward).
        train_set, val_set: torch datasets (``val_set`` may be None: then the training loss selects).
        cfg: optimisation settings (epochs, batch size, lr, seed, ...).
        collate_fn: items -> batch with ``.to(device)`` and ``.size``.
        output: best-checkpoint path ('-': kept in memory, written by the caller).
        config, norm_stats, history, extra: stored in every checkpoint (see ``checkpoint.py``).
        env: distributed environment (default: single process on CPU).
        resume: continue from ``<stem>.last.pt``.
        watch: the epoch bar, batch bars and per-epoch callbacks (:class:`lesscli.train.watch.Watch`;
            default: nothing shown).
        data: :func:`data_identity` of the training data, stored in ``<stem>.last.pt``; ``resume``
            refuses a run whose data differs.
        val_fn: ``val_fn(model, loader, device) -> (mean loss, score)``, one pass over the validation
            loader (called in evaluation mode without gradients). A score (higher is better; None or
            NaN: none) selects the best epoch, ties broken by the loss. Default: :func:`loss_only`.
        record_extra: constant values added to every epoch record (e.g. a baseline to compare with).

    Returns:
        :class:`FitResult` (``best_state`` is the best model's CPU state dict).

    Raises:
        TrainingError: non-finite loss or gradient (names the epoch, batch and global step).
    """
    env = env or distributed.DistEnv()
    info = {"config": config, "norm_stats": norm_stats, "history": history or [], "extra": extra,
            "data": data}
    watch = watch or Watch()
    trainer = _Trainer(model, loss_fn, cfg, env, output, info, watch)
    train_loader = _loader(train_set, cfg, collate_fn, env, True, trainer.data_gen)
    val_loader = _loader(val_set, cfg, collate_fn, distributed.DistEnv(), False, trainer.data_gen) \
        if val_set is not None and len(val_set) else None
    trainer.make_schedule(len(train_loader))
    if resume:
        trainer.resume()
    elif env.is_main and trainer.log_path and os.path.exists(trainer.log_path):
        os.remove(trainer.log_path)
    bar = watch.epochs(range(trainer.start_epoch, cfg.epochs), desc="train", unit="epoch", total=cfg.epochs,
                       initial=trainer.start_epoch)
    for epoch in bar:
        t0 = time.perf_counter()
        train_loss = trainer.run_epoch(train_loader, epoch)
        val_loss = val_score = None
        if val_loader:
            val_loss, val_score = validate(val_fn or loss_only(loss_fn), trainer.raw, val_loader, env.device)
            trainer.guard(val_loss, "validation loss", epoch, len(val_loader) - 1)
        record = trainer.end_epoch(epoch, train_loss, val_loss, val_score, time.perf_counter() - t0,
                                   record_extra)
        if hasattr(bar, "set_postfix"):
            bar.set_postfix(bar_postfix(record, trainer.best_record(record)))
    if hasattr(bar, "close"):
        bar.close()
    trainer.finish()
    return trainer.result
