"""Batch prediction: per scan (and per sequence prefix) class probabilities, labels, entropy, truth.

Each scan is imaged on its own label grid when it has one (3D: the volume's grid; 2D: the slice
through the inclusion centre, or the trained slice index), else on the training grid. ``steps``/
``every`` image prefixes of the scan's sequence (the image developing over time); ``grow`` extends
the particle grid over the largest label grid at the same particle spacing (weights are shared).
``turns`` 2 or 4 averages the probabilities of the scan turned by each half or quarter turn about the
insert's axis (its poses turned, the image turned back): the model reads the same touches at other
angles, at that many times the prediction's cost.
A force-map calibration (``less image fit --model forcemap``) predicts on the same grids
(:func:`predict_forcemap`); :func:`predict_file` tells the two checkpoint kinds apart.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from lesscli.data.batching import ScanDataset, check_force_features, collate
from lesscli.data.compat import for_model
from lesscli.data.image_labels import AUTO_SLICE, grid_of, target_volume
from lesscli.errors import DataError, LessError
from lesscli.infer import forcemap
from lesscli.io.checkpoint import load_checkpoint
from lesscli.io.predictions import Labelling, PredictionSet, ScanPrediction, nothing_known, scan_numbers
from lesscli.io.scans import ScanSet, load_scans
from lesscli.models.imager import Imager, grid_from_dict
from lesscli.sim.state import rotate_pose
from lesscli.types import ImageGrid

TURNS = (1, 2, 4)                # predictions averaged over the scan turned by 360 / turns degrees each
GRID_CENTRE_TOL = 1e-3           # a label grid centred on the insert's axis to this share of a pixel


@dataclass(kw_only=True)
class PredictOptions:
    """How to predict.

    Attributes:
        threshold: pillar/inclusion only above this probability (None: the checkpoint's
            ``config['image']['threshold']``, chosen on validation data by ``image fit``; else argmax).
        steps: image this many evenly spaced prefixes per scan (None: the whole sequence only).
        every: image every K-th prefix (and the whole sequence); exclusive with ``steps``.
        grow: extend the particle grid over larger label grids.
        batch_size: prefixes per forward pass.
        slice_index: 2D slice rule (default: the model's training rule).
        min_volume_mm3: inclusion regions smaller than this are dropped (None: the checkpoint's
            ``config['image']['min_volume_mm3']``, chosen on validation data by ``image fit``; else 0).
        smooth_mm: label from probabilities smoothed across each slice by a Gaussian of this standard
            deviation (None: the checkpoint's ``config['image']['smooth_mm']``, chosen the same way; else 0).
        turns: 1, or 2 / 4: average over the scan turned by half / quarter turns (module docstring).
    """

    threshold: float | None = None
    steps: int | None = None
    every: int | None = None
    grow: bool = False
    batch_size: int = 4
    slice_index: int | None = None
    min_volume_mm3: float | None = None
    smooth_mm: float | None = None
    turns: int = 1


def load_imager(path: str, map_location: str | torch.device = "cpu",
                ckpt: dict | None = None) -> tuple[Imager, dict]:
    """Rebuild an imaging model from its checkpoint (eval mode); DataError names the file.

    ``ckpt``: the checkpoint already loaded from ``path`` (None: load it).
    """
    from lesscli.models.registry import build_decoder, build_encoder

    ckpt = load_checkpoint(path, map_location) if ckpt is None else ckpt
    cfg = ckpt.get("config", {})
    if cfg.get("model") == forcemap.MODEL:
        raise DataError(f"{path}: a force-map calibration, not a learned imager; "
                        "only 'less image predict' reads it")
    missing = [k for k in ("encoder", "decoder", "grid", "image") if k not in cfg]
    if missing:
        raise DataError(f"{path}: not an imaging checkpoint (config lacks {', '.join(missing)}); "
                        "make one with 'less image fit'")
    check_image_config(cfg["image"], path)
    try:
        imager = Imager(build_encoder(cfg["encoder"]), build_decoder(cfg["decoder"]),
                        grid_from_dict(cfg["grid"]))
    except LessError as exc:
        raise DataError(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise DataError(f"{path}: malformed model config ({type(exc).__name__}: {exc})") from None
    try:
        imager.load_state_dict(ckpt["model_state"])
    except RuntimeError as exc:
        raise DataError(f"{path}: weights do not match the model config "
                        f"({str(exc).splitlines()[0]})") from None
    return imager.to(map_location).eval(), ckpt


def check_image_config(image, path: str) -> None:
    """An imaging checkpoint's ``config['image']``: dim 2 or 3, slice a whole number, threshold None or 0..1,
    minimum inclusion volume None or >= 0 mm^3, smoothing None or >= 0 mm."""
    if not isinstance(image, dict):
        raise DataError(f"{path}: config 'image' must be a table, got {type(image).__name__}")
    if image.get("dim") not in (2, 3):
        raise DataError(f"{path}: config image.dim must be 2 or 3, got {image.get('dim')!r}")
    if not isinstance(image.get("slice", AUTO_SLICE), int):
        raise DataError(f"{path}: config image.slice must be a whole number, got {image.get('slice')!r}")
    for key, top, what in (("threshold", 1.0, "a probability 0..1"),
                           ("min_volume_mm3", float("inf"), "a volume >= 0 mm^3"),
                           ("smooth_mm", float("inf"), "a length >= 0 mm")):       # the labelling rule
        value = image.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not 0 <= value <= top or value == float("inf")):
            raise DataError(f"{path}: config image.{key} must be {what}, got {value!r}")


def labelling_rule(image_cfg: dict, threshold: float | None = None, min_volume_mm3: float | None = None,
                   smooth_mm: float | None = None) -> Labelling:
    """The labelling rule to apply: each part as given, else the model's (``config['image']``, chosen
    on validation data by ``image fit``), else argmax, no region rule, no smoothing (a model fitted
    before a part existed labels as it did then)."""
    return Labelling(threshold if threshold is not None else image_cfg.get("threshold"),
                     float(min_volume_mm3 if min_volume_mm3 is not None else image_cfg.get("min_volume_mm3")
                           or 0.0),
                     float(smooth_mm if smooth_mm is not None else image_cfg.get("smooth_mm") or 0.0))


def scans_for_model(path: str, ckpt: dict, model_name: str = "the model") -> ScanSet:
    """The scan set at ``path``, checked against the model's units, sensor layout and force features and put
    in the frame its imager reads (DataError names the file)."""
    scans = for_model(load_scans(path), ckpt, model_name, path)
    check_force_features(scans, ckpt["norm_stats"], path)
    return scans


def prefix_lengths(n_steps: int, steps: int | None = None, every: int | None = None) -> list[int]:
    """Prefix lengths to image: evenly spaced ``steps`` of them, every ``every``-th, or just ``n_steps``."""
    if steps:
        return sorted({max(1, math.ceil(n_steps * i / steps))
                       for i in range(1, steps + 1)}) if n_steps else [0]
    if every:
        return [*range(every, n_steps, every), n_steps] if n_steps else [0]
    return [n_steps]


def scan_grid(scans: ScanSet, s: int, dim: int, slice_index: int,
              default: ImageGrid) -> tuple[ImageGrid, np.ndarray | None]:
    """Output grid and truth (D, H, W) of scan ``s``; the training grid and None without a label."""
    label = scans.label_of(s)
    if label is None:
        return default, None
    vol = target_volume(label, dim, slice_index)
    return grid_of(vol), vol.data


def grow_extent_mm(grids: list[ImageGrid]) -> float:
    """Side of the square particle grid that covers every grid's x-y extent."""
    return max(max(g.shape[1] * g.spacing_mm[1], g.shape[2] * g.spacing_mm[2]) for g in grids)


def _prefix_item(item: dict, k: int) -> dict:
    return {**item, "pose": item["pose"][:k], "force": item["force"][:k]}


def predict_scan(imager: Imager, item: dict, lengths: list[int], grid: ImageGrid, batch_size: int,
                 device: torch.device) -> list[np.ndarray]:
    """Probabilities (C, D, H, W) float32 for each prefix length of one scan."""
    out = []
    for lo in range(0, len(lengths), batch_size):
        batch = collate([_prefix_item(item, k) for k in lengths[lo:lo + batch_size]]).to(device)
        with torch.no_grad():
            probs = torch.softmax(imager(batch, grid), dim=1)
        out.extend(probs.float().cpu().numpy())
    return out


def quarter_turns(turns: int) -> list[int]:
    """Quarter turns (multiples of 90 degrees about the insert's axis) averaged for ``turns``."""
    if turns not in TURNS:
        raise LessError(f"turns must be one of {', '.join(map(str, TURNS))}, got {turns}")
    return list(range(0, 4, 4 // turns))


def turned(scans: ScanSet, quarters: int) -> ScanSet:
    """The scan set with its poses turned by ``quarters`` x 90 degrees about the insert's axis, yaw kept in
    [0, 2 pi) (the pose encoding is not periodic in yaw, so four quarter turns give back the scan)."""
    pose = rotate_pose(scans.pose.astype(np.float64), 2 * quarters)
    pose[:, 5] = np.mod(pose[:, 5], 2 * math.pi)
    return dataclasses.replace(scans, pose=pose.astype(scans.pose.dtype))


def check_turnable(grid: ImageGrid, where: str) -> None:
    """A grid that a quarter turn about the insert's axis maps onto itself (LessError otherwise)."""
    (_, h, w), (_, dy, dx), (_, oy, ox) = grid.shape, grid.spacing_mm, grid.origin_mm
    centred = all(abs(o + (n - 1) / 2 * d) <= GRID_CENTRE_TOL * d for o, n, d in ((oy, h, dy), (ox, w, dx)))
    if h != w or not math.isclose(dy, dx, rel_tol=1e-6) or not centred:
        raise LessError(f"{where}: --turns needs a square label grid centred on the insert's axis, got "
                        f"{h} x {w} pixels of {dy:g} x {dx:g} mm from ({oy:g}, {ox:g}) mm")


# a step touches where its total force exceeds this share of the scan's largest
CONTACT_SHARE = 0.1
MAX_TOUCH_MARKS = 2000          # touches stored per prediction (evenly thinned beyond)


def touch_points(scans: ScanSet, s: int, steps: int) -> np.ndarray:
    """(T, 2) float32: x, y (mm) of the pad's centre at the steps among the first ``steps`` of scan ``s``
    that were in contact, i.e. whose total force (the norm of the taxels' summed force) exceeds
    :data:`CONTACT_SHARE` of the scan's largest; at most :data:`MAX_TOUCH_MARKS`, evenly thinned."""
    sl = scans.scan_steps(s)
    force = np.linalg.norm(scans.force[sl].astype(np.float64).sum(axis=1), axis=-1)
    if not force.size or force.max() <= 0:
        return np.zeros((0, 2), np.float32)
    seen = np.flatnonzero(force[:steps] > CONTACT_SHARE * force.max())
    if len(seen) > MAX_TOUCH_MARKS:
        seen = seen[np.linspace(0, len(seen) - 1, MAX_TOUCH_MARKS).round().astype(int)]
    return scans.pose[sl][seen, :2].astype(np.float32)


def _scan_prediction(scans: ScanSet, s: int, probs: np.ndarray, grid: ImageGrid, truth: np.ndarray | None,
                     steps: int, labelling: Labelling) -> ScanPrediction:
    """One prediction record; a prefix of 0 steps images as nothing known (uniform probabilities)."""
    if steps == 0:
        probs = nothing_known(probs.shape)
    return ScanPrediction(probs=probs, origin_mm=np.array(grid.origin_mm),
                          spacing_mm=np.array(grid.spacing_mm), truth=truth, insert=str(scans.scan_insert[s]),
                          orientation=int(scans.scan_orientation[s]), steps=int(steps),
                          label=labelling.labels(probs, grid.spacing_mm), scan=int(s),
                          touch_xy_mm=touch_points(scans, s, steps))


def predict(imager: Imager, ckpt: dict, scans: ScanSet, opts: PredictOptions,
            device: torch.device | str = "cpu", name: str = "scan set", progress: Callable = lambda it,
            **_: it) -> PredictionSet:
    """Predict every scan of ``scans`` (see the module docstring)."""
    device = torch.device(device)
    cfg = ckpt["config"]
    dim = int(cfg["image"]["dim"])
    slice_index = int(cfg["image"].get("slice", AUTO_SLICE)) if opts.slice_index is None else opts.slice_index
    grids = [scan_grid(scans, s, dim, slice_index, imager.grid) for s in range(scans.n_scans)]
    if opts.grow and grids:
        imager.encoder = imager.encoder.with_grid(grow_extent_mm([g for g, _ in grids]))
    imager = imager.to(device).eval()
    labelling = labelling_rule(cfg["image"], opts.threshold, opts.min_volume_mm3, opts.smooth_mm)
    quarters = quarter_turns(opts.turns)
    if len(quarters) > 1:
        for s, (grid, _) in enumerate(grids):
            check_turnable(grid, f"{name}: scan {s}")
    data = [ScanDataset(turned(scans, q) if q else scans, ckpt["norm_stats"], name) for q in quarters]
    offsets = scans.scan_step_offsets()
    preds = []
    for s in progress(range(scans.n_scans), desc="predict", leave=False):
        grid, truth = grids[s]
        lengths = prefix_lengths(int(offsets[s + 1] - offsets[s]), opts.steps, opts.every)
        mean = [0.0] * len(lengths)
        for q, turned_data in zip(quarters, data):      # each image turned back onto the scan's grid
            out = predict_scan(imager, turned_data[s], lengths, grid, opts.batch_size, device)
            mean = [m + np.rot90(p, k=q, axes=(-2, -1)) / len(quarters) for m, p in zip(mean, out)]
        for k, probs in zip(lengths, mean):
            preds.append(_scan_prediction(scans, s, np.ascontiguousarray(probs, dtype=np.float32), grid,
                                          truth, k, labelling))
    meta = {"dim": dim, **labelling.to_dict(), "turns": int(opts.turns), "model": cfg["encoder"]["name"],
            "decoder": cfg["decoder"]["name"], "width": cfg["decoder"].get("width"), "grown": bool(opts.grow),
            "particles": int(getattr(imager.encoder, "n_particles", 1)),
            "seed": cfg.get("train", {}).get("seed")}
    return PredictionSet(preds, meta)


def predict_forcemap(ckpt: dict, scans: ScanSet, opts: PredictOptions, path: str, name: str = "scan set",
                     progress: Callable = lambda it, **_: it) -> PredictionSet:
    """Force-map predictions (:mod:`lesscli.infer.forcemap`) of every scan and prefix, on the grids
    :func:`predict` uses; ``path`` names the checkpoint in errors, ``name`` the scan set."""
    cfg = ckpt["config"]
    if opts.turns != 1:
        raise LessError(f"{path}: --turns averages a learned imager's readings of the turned scan; the force "
                        "map places each touch in the insert's frame, so turning it changes nothing")
    cal = forcemap.calibration_from_dict(cfg.get("forcemap") or {}, path)
    try:
        dim, default = int(cfg["image"]["dim"]), grid_from_dict(cfg["grid"])
        slice_index = int(cfg["image"]["slice"]) if opts.slice_index is None else opts.slice_index
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{path}: malformed force-map checkpoint (config 'image'/'grid': {exc!r})") from None
    taxel_xy = forcemap.taxel_layout(scans.meta, name)
    labelling = labelling_rule({}, opts.threshold, opts.min_volume_mm3, opts.smooth_mm)
    offsets, preds = scans.scan_step_offsets(), []
    for s in progress(range(scans.n_scans), desc="predict", leave=False):
        grid, truth = scan_grid(scans, s, dim, slice_index, default)
        for k in prefix_lengths(int(offsets[s + 1] - offsets[s]), opts.steps, opts.every):
            probs = forcemap.scan_probs(cal, forcemap.scan_touches(scans, s, taxel_xy, k), grid.shape,
                                        grid.origin_mm, grid.spacing_mm)
            preds.append(_scan_prediction(scans, s, probs, grid, truth, k, labelling))
    meta = {"dim": dim, **labelling.to_dict(), "model": forcemap.MODEL, "decoder": None, "width": None,
            "grown": False, "particles": None, "seed": None}
    return PredictionSet(preds, meta)


def predict_file(path: str, data: str, opts: PredictOptions, device: torch.device | str = "cpu",
                 progress: Callable = lambda it, **_: it) -> tuple[PredictionSet, dict, ScanSet]:
    """Load the checkpoint at ``path`` and the scan set ``data`` and predict: the one place that tells a
    force-map calibration (``config['model'] == 'forcemap'``) from a learned imager.

    Returns:
        (predictions, checkpoint, scans).
    """
    ckpt = load_checkpoint(path, device)
    if ckpt.get("config", {}).get("model") == forcemap.MODEL:
        scans = for_model(load_scans(data), ckpt, path, data)
        return predict_forcemap(ckpt, scans, opts, path, data, progress), ckpt, scans
    imager, ckpt = load_imager(path, device, ckpt)
    scans = for_model(load_scans(data), ckpt, path, data)
    return predict(imager, ckpt, scans, opts, device, data, progress), ckpt, scans


def write_nifti(preds: PredictionSet, folder: str) -> list[str]:
    """Label, entropy and class-probability volumes per prediction as NIfTI with their affine, and the
    class colour tables for 3D Slicer and ITK-SNAP (lesscli.io.colour_tables); all or none written.

    Files are ``<scan>_<insert>_o<orientation>[_t<steps>]_labels.nii.gz`` (uint8 codes, NIfTI intent
    "label"), ``..._entropy.nii.gz`` (nats) and ``..._prob_<class>.nii.gz`` (one float32 map per class),
    plus ``labels.ctbl`` and ``labels_itksnap.txt``; returns their paths (in ``folder``).
    """
    from lesscli.io.atomic import atomic_dir
    from lesscli.io.colour_tables import write_colour_tables
    from lesscli.io.labels import CLASS_NAMES, save_nifti, save_nifti_array
    from lesscli.plots.palette import CLASS_RGBA

    scan_of = scan_numbers(preds.scans)
    multi = np.bincount(scan_of, minlength=1) > 1 if scan_of else np.zeros(0, bool)
    paths = []
    with atomic_dir(folder) as tmp:
        for i, p in enumerate(preds.scans):
            stem = f"{scan_of[i]:03d}_{p.insert or 'scan'}_o{p.orientation}"
            if multi[scan_of[i]]:
                stem += f"_t{p.steps}"
            vol = p.label_volume()
            names = [f"{stem}_labels.nii.gz", f"{stem}_entropy.nii.gz"]
            save_nifti(os.path.join(tmp, names[0]), vol, intent="label")
            save_nifti_array(os.path.join(tmp, names[1]), p.entropy.astype(np.float32), vol)
            for code, cls in enumerate(CLASS_NAMES):
                names.append(f"{stem}_prob_{cls}.nii.gz")
                save_nifti_array(os.path.join(tmp, names[-1]), np.asarray(p.probs[code], np.float32), vol)
            paths += [os.path.join(folder, n) for n in names]
        tables = write_colour_tables(tmp, CLASS_NAMES, CLASS_RGBA)
        paths += [os.path.join(folder, os.path.basename(t)) for t in tables]
    return paths
