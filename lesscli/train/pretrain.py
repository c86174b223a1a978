"""Self-supervised pretraining of a LESS or GLOBAL representation by force prediction."""

from __future__ import annotations

import inspect
import time

import torch

from lesscli.data.batching import ScanDataset, collate, compute_norm_stats, force_dim
from lesscli.errors import DataError, LessError
from lesscli.io.scans import ScanSet
from lesscli.models.registry import ENCODERS, lookup
from lesscli.models.ssl_loss import ForcePredictor
from lesscli.train import distributed
from lesscli.train.config import ModelConfig, PretrainConfig, check_pretrain_config, to_dict
from lesscli.train.loop import EVAL_SEED, FitResult, data_identity, fit
from lesscli.train.watch import Watch

MAP_SETTINGS = ("map_contrast", "map_cells", "map_pitch_mm")   # model settings of less-taxel's stiffness map


def encoder_kwargs(cfg: PretrainConfig, n_force: int, taxel_xy_mm: list | None = None) -> dict:
    """Constructor arguments of the configured encoder (``taxel_xy_mm`` for encoders that take it)."""
    m = cfg.model
    kwargs = {"force_dim": n_force, "dim": m.dim, "spacing_mm": m.spacing_mm,
              "grid_extent_mm": m.grid_extent_mm, "receptive_field_mm": m.receptive_field_mm,
              "n_freq": m.n_freq, "max_steps_per_particle": m.max_steps_per_particle or None}
    params = inspect.signature(lookup(ENCODERS, m.name, "encoder")).parameters
    if "taxel_xy_mm" in params:
        if taxel_xy_mm is None:
            raise DataError(f"encoder '{m.name}' needs the sensor's taxel layout (meta sensor.taxel_xy_mm)")
        kwargs["taxel_xy_mm"] = taxel_xy_mm
    for key in MAP_SETTINGS:                    # the stiffness map's settings (less-taxel)
        value = getattr(m, key)
        if key in params:
            kwargs[key] = value
        elif value != getattr(ModelConfig, key):
            raise LessError(f"setting model.{key} = {value!r} applies to less-taxel only, not to encoder "
                            f"'{m.name}'")
    return kwargs


def taxel_layout(scans: ScanSet, name: str = "scan set") -> list | None:
    """The scan set's taxel centres in the pad frame (meta sensor.taxel_xy_mm), None when not recorded."""
    sensor = scans.meta.get("sensor") if isinstance(scans.meta, dict) else None
    xy = sensor.get("taxel_xy_mm") if isinstance(sensor, dict) else None
    if xy is None:
        return None
    if len(xy) != scans.n_taxels or any(not isinstance(v, list) or len(v) != 2 for v in xy):
        raise DataError(f"{name}: meta sensor.taxel_xy_mm must hold {scans.n_taxels} [x, y] pairs")
    return [[float(a), float(b)] for a, b in xy]


def build_model(cfg: PretrainConfig, n_force: int, taxel_xy_mm: list | None = None) -> ForcePredictor:
    """Encoder + its force decoder, initialised from ``cfg.train.seed`` (the global RNG is restored after)."""
    cls = lookup(ENCODERS, cfg.model.name, "encoder")
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.train.seed)
        encoder = cls(**encoder_kwargs(cfg, n_force, taxel_xy_mm))
        decoder = encoder.force_decoder()
    return ForcePredictor(encoder, decoder, cfg.ssl.k_input, cfg.ssl.k_query)


def ssl_loss_fn(model, batch, generator: torch.Generator) -> torch.Tensor:
    """Loss callable for :func:`lesscli.train.loop.fit`: the model's forward returns the SSL loss."""
    return model(batch, generator)


def force_mse(model: ForcePredictor, dataset: ScanDataset, batch_size: int, device: torch.device,
              baseline: bool = False) -> float:
    """Mean force-prediction MSE (normalised units) over ``dataset`` with the fixed evaluation draws;
    ``baseline``: of predicting the training mean (0 after normalisation) on the same draws."""
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, collate_fn=collate)
    model = model.to(device).eval()
    gen = torch.Generator().manual_seed(EVAL_SEED)
    total, n = 0.0, 0
    with torch.no_grad():
        for batch in loader:
            total += float(model(batch.to(device), gen, baseline=baseline)) * batch.size
            n += batch.size
    return total / max(1, n)


def force_errors(model: ForcePredictor, dataset: ScanDataset, batch_size: int,
                 device: torch.device) -> dict:
    """Validation force-prediction MSE of the model and of predicting the mean, and their ratio."""
    scores = {name: force_mse(model, dataset, batch_size, device, baseline)
              for name, baseline in (("mse", False), ("baseline_mse", True))}
    scores["ratio"] = scores["mse"] / scores["baseline_mse"] if scores["baseline_mse"] > 0 else float("nan")
    return scores


def pretrain(train: ScanSet, val: ScanSet | None, cfg: PretrainConfig, output: str, *,
             env: distributed.DistEnv | None = None, resume: bool = False, history: list | None = None,
             watch: Watch | None = None, names: tuple[str, str] = ("train", "val")) -> dict:
    """Train a representation and write the best checkpoint to ``output``.

    With ``val``, every epoch record also holds ``val_baseline_mse``, the validation force MSE of
    predicting the training mean on the same draws as ``val_loss`` (their ratio is the force error
    against the mean baseline, per epoch).

    Returns:
        A summary record: epochs, best epoch, best validation (or training) loss, and the
        validation force MSE against the predict-the-mean baseline when ``val`` is given.
    """
    env = env or distributed.DistEnv()
    check_pretrain_config(cfg)
    t0 = time.perf_counter()
    norm = cfg.model.force_norm or lookup(ENCODERS, cfg.model.name, "encoder").force_norm
    stats = compute_norm_stats(train, norm)
    train_set = ScanDataset(train, stats, names[0])
    val_set = ScanDataset(val, stats, names[1]) if val is not None else None
    model = build_model(cfg, force_dim(stats), taxel_layout(train, names[0]))
    config = {**to_dict(cfg), "encoder": model.encoder.config(),
              "decoder": {"name": model.decoder.name, **model.decoder.settings}}
    has_val = val_set is not None and len(val_set) > 0
    baseline = {"val_baseline_mse": force_mse(model, val_set, cfg.train.batch_size, env.device,
                                              baseline=True)} \
        if has_val else None
    result: FitResult = fit(model, ssl_loss_fn, train_set, val_set, cfg.train, collate_fn=collate,
                            output=output, config=config, norm_stats=stats, env=env, resume=resume,
                            history=history, watch=watch, record_extra=baseline,
                            data=data_identity(train, stats, names[0]))
    summary = {"output": output, "model": cfg.model.name, "particles": model.encoder.n_particles,
               "parameters": sum(p.numel() for p in model.parameters()), "epochs": cfg.train.epochs,
               "best_epoch": result.best_epoch + 1, "best_loss": result.best_loss,
               "selected_by": "val_loss" if has_val else "train_loss"}
    if has_val and result.best_state is not None:
        model.load_state_dict(result.best_state)
        summary.update({f"val_{k}": v for k, v in
                        force_errors(model, val_set, cfg.train.batch_size, env.device).items()})
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    return summary
