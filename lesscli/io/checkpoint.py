"""Self-describing checkpoints, loadable with ``torch.load(..., weights_only=True)``.

A checkpoint is a dict of tensors and plain Python values::

    {"format": "less.checkpoint", "version": 1,
     "model_state": {name: tensor},     # e.g. "encoder.*" and "decoder.*" for a representation
     "config": {...},                   # resolved config; config["encoder"] = encoder.config()
     "norm_stats": {...},               # lesscli.data.batching.compute_norm_stats of the training set
     "history": [...],                  # per-epoch records and command history
     "extra": {...}}

Any checkpoint whose ``config["encoder"]`` is an encoder config and whose model state holds the
encoder under the prefix ``encoder.`` can be opened with ``lesscli.train.representation.load_representation``
(pretraining writes such files; an imaging model that keeps its encoder as the submodule ``encoder`` and
copies the representation's ``config["encoder"]`` does too).
"""

from __future__ import annotations

import io
import os
import pickle
import zipfile

import numpy as np
import torch

from lesscli.errors import DataError
from lesscli.io.atomic import atomic_path

FORMAT, VERSION = "less.checkpoint", 1
ENCODER_PREFIX = "encoder."
LOAD_ERRORS = (pickle.UnpicklingError, zipfile.BadZipFile, RuntimeError, EOFError, OSError, ValueError,
               KeyError, AttributeError, TypeError)


def save_checkpoint(path: str, model_state: dict, config: dict, norm_stats: dict, history: list,
                    extra: dict | None = None) -> None:
    """Write a checkpoint atomically (temp file + rename).

    Args:
        path: output ``.pt`` path.
        model_state: state dict (tensors are moved to CPU).
        config: resolved configuration (plain values only).
        norm_stats: normalisation statistics of the training set.
        history: list of plain dicts.
        extra: more plain values or tensors (optimizer state, RNG states, ...).
    """
    payload = {"format": FORMAT, "version": VERSION,
               "model_state": {k: v.detach().cpu() for k, v in model_state.items()},
               "config": config, "norm_stats": norm_stats, "history": list(history), "extra": extra or {}}
    buffer = io.BytesIO()              # serialised in memory first: a full disk then fails as an OSError
    torch.save(payload, buffer)        # naming the file (torch's own writer raises an internal error)
    with atomic_path(path, ".pt") as tmp, open(tmp, "wb") as fh:
        fh.write(buffer.getbuffer())


def load_checkpoint(path: str, map_location: str | torch.device = "cpu") -> dict:
    """Read and check a checkpoint (``weights_only=True``); DataError names the file and problem."""
    if not os.path.exists(path):
        raise DataError(f"{path}: no such checkpoint")
    if os.path.isfile(path) and os.path.getsize(path) == 0:
        raise DataError(f"{path}: not a readable checkpoint (the file is empty)")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except LOAD_ERRORS as exc:  # torch raises many types for corrupt or foreign files
        first = str(exc).splitlines()[0].split(". ")[0] if str(exc) else ""
        raise DataError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {first})") from None
    check_checkpoint(ckpt, path)
    return ckpt


def check_checkpoint(ckpt, path: str) -> None:
    """The checkpoint layout (module docstring): format, version, and the type of every part."""
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise DataError(f"{path}: not a less checkpoint (expected format '{FORMAT}')")
    version = ckpt.get("version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise DataError(f"{path}: checkpoint 'version' must be a whole number, got {version!r}")
    if version > VERSION:
        raise DataError(f"{path}: checkpoint version {version} is newer than this toolkit ({VERSION})")
    for key, kind in (("model_state", dict), ("config", dict), ("norm_stats", dict), ("history", list)):
        if not isinstance(ckpt.get(key), kind):
            raise DataError(f"{path}: checkpoint '{key}' must be a {kind.__name__}, got "
                            f"{type(ckpt.get(key)).__name__}")
    if not all(isinstance(v, torch.Tensor) for v in ckpt["model_state"].values()):
        raise DataError(f"{path}: checkpoint 'model_state' must map names to tensors")
    _check_finite_weights(ckpt["model_state"], path)
    if not isinstance(ckpt.get("extra", {}), dict):
        raise DataError(f"{path}: checkpoint 'extra' must be a dict")
    _check_norm_stats(ckpt["norm_stats"], path)


def _check_finite_weights(state: dict, path: str) -> None:
    """Every floating-point weight finite: a checkpoint of a run that diverged is named as the problem
    here, not the output it would have produced."""
    for name, tensor in state.items():
        if tensor.is_floating_point() or tensor.is_complex():
            bad = int((~torch.isfinite(tensor)).sum())
            if bad:
                raise DataError(f"{path}: weight '{name}' holds NaN or inf ({bad} of {tensor.numel()} "
                                "values); the checkpoint is broken (a diverged run?): train again or use "
                                "another one")


def _check_norm_stats(stats: dict, path: str) -> None:
    """Normalisation statistics, when present: equal-length finite means and positive scales."""
    if not stats:
        return
    try:
        mean = np.asarray(stats["force_mean"], np.float64)
        std = np.asarray(stats["force_std"], np.float64)
    except (KeyError, TypeError, ValueError):
        raise DataError(f"{path}: 'norm_stats' needs number lists 'force_mean' and 'force_std'") from None
    if mean.ndim != 1 or mean.shape != std.shape or not mean.size:
        raise DataError(f"{path}: 'norm_stats' force_mean and force_std must be equal-length lists")
    if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
        raise DataError(f"{path}: 'norm_stats' must be finite with positive force_std")


def encoder_state(model_state: dict) -> dict:
    """The ``encoder.*`` entries of a state dict, prefix removed."""
    n = len(ENCODER_PREFIX)
    return {k[n:]: v for k, v in model_state.items() if k.startswith(ENCODER_PREFIX)}
