"""End to end through the CLI: pretrain -> image fit -> image predict (-> render, mesh)."""

import json
import math

import nibabel as nib
import numpy as np
import pytest
import torch
from imaging_factory import TOUCH_X_MM, learnable_scanset, make_representation

from lesscli.io.checkpoint import encoder_state
from lesscli.io.labels import INCLUSION
from lesscli.io.predictions import load_predictions
from lesscli.io.scans import save_scans

ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TOUCHED_MM, UNTOUCHED_MM = 3.0, 20.0     # pixel-to-nearest-touch distances defining the two regions


def _ok(proc):
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return [json.loads(line) for line in proc.stdout.decode().splitlines() if line.strip()]


def _micro_f1(preds):
    tp = fp = fn = 0
    for p in preds.scans:
        true, pred = p.truth == INCLUSION, p.label == INCLUSION
        tp, fp, fn = (tp + int((true & pred).sum()), fp + int((~true & pred).sum()),
                      fn + int((true & ~pred).sum()))
    return 2 * tp / max(1, 2 * tp + fp + fn)


def _touch_distance_mm(pred, scans, s):
    """(H, W) distance from each pixel centre to the nearest touch of scan s, mm."""
    (_, y0, x0), (_, dy, dx) = pred.origin_mm, pred.spacing_mm
    h, w = pred.label.shape[1:]
    yy, xx = np.meshgrid(y0 + dy * np.arange(h), x0 + dx * np.arange(w), indexing="ij")
    touches = scans.pose[scans.scan_steps(s), :2]
    d2 = (xx[..., None] - touches[:, 0]) ** 2 + (yy[..., None] - touches[:, 1]) ** 2
    return np.sqrt(d2.min(axis=-1))


@pytest.fixture
def sets(tmp_path):
    test = learnable_scanset(3, 32)
    for name, scans in (("train", learnable_scanset(8, 10)), ("val", learnable_scanset(2, 21)),
                        ("test", test)):
        save_scans(str(tmp_path / f"{name}.npz"), scans)
    return test


def test_pretrain_fit_predict_beats_no_inclusion_with_honest_entropy(tmp_path, run_less, sets):
    _ok(run_less("pretrain", "train.npz", "--val", "val.npz", "-o", "rep.pt", "--dim", "16", "--epochs", "3",
                 "--lr", "3e-3", "--device", "cpu", "--format", "jsonl", env=ONE_THREAD))
    (fit,) = _ok(run_less("image", "fit", "train.npz", "--val", "val.npz", "--rep", "rep.pt", "-o", "img.pt",
                          "--dim", "2", "--epochs", "15", "--lr", "1e-2", "--device", "cpu", "--set",
                          "image.width=16", "--set", "image.patch_px=8", "--format", "jsonl", env=ONE_THREAD))
    assert fit["frozen"] and fit["decoder"] == "patch" and fit["val_inclusion_f1"] > 0
    log = [json.loads(line) for line in (tmp_path / "img.log.jsonl").read_text().splitlines()]
    assert len(log) == 15 and all(math.isfinite(r["train_loss"]) for r in log)
    assert fit["selected_by"] == "val_f1" and fit["best_epoch"] == max(
        (r for r in log if "val_score" in r), key=lambda r: (r["val_score"], -r["val_loss"]))["epoch"]
    (summary,) = _ok(run_less("image", "predict", "img.pt", "test.npz", "-o", "pred.npz", "--device", "cpu",
                              "--format", "jsonl", env=ONE_THREAD))
    assert summary["predictions"] == 3
    preds = load_predictions(str(tmp_path / "pred.npz"))
    assert preds.meta["dim"] == 2 and all(p.probs.shape[:2] == (4, 1) for p in preds.scans)
    f1 = _micro_f1(preds)
    assert f1 > 0.0          # predicting no inclusion scores F1 = 0 on scans that all have one
    touched, untouched = [], []
    for s, p in enumerate(preds.scans):
        dist = _touch_distance_mm(p, sets, s)
        touched.append(p.entropy[0][dist < TOUCHED_MM])
        untouched.append(p.entropy[0][dist > UNTOUCHED_MM])
    touched, untouched = np.concatenate(touched), np.concatenate(untouched)
    assert untouched.size > 0 and touched.size > 0
    assert touched.mean() < untouched.mean()
    print(f"imaging pipeline: test inclusion F1 {f1:.3f}, entropy touched {touched.mean():.3f} "
          f"< untouched {untouched.mean():.3f} nats (x touches in {TOUCH_X_MM} mm)")


def test_3d_fit_predict_steps_threshold_nifti_render_mesh(tmp_path, run_less, sets):
    from lesscli.io.scans import load_scans

    make_representation(str(tmp_path / "rep.pt"), load_scans(str(tmp_path / "train.npz")))
    _ok(run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "img3.pt", "--dim", "3", "--epochs",
                 "2", "--lr", "1e-2", "--device", "cpu", "--set", "image.width=16", "--set",
                 "image.patch_px=8", env=ONE_THREAD))
    (summary,) = _ok(run_less("image", "predict", "img3.pt", "test.npz", "-o", "pred3.npz", "--steps", "2",
                              "--threshold", "0.8", "--nifti", "nii", "--device", "cpu", "--format", "jsonl",
                              env=ONE_THREAD))
    # per image: labels, entropy and 4 class probability maps; and the two colour tables
    assert summary["predictions"] == 6 and summary["nifti_files"] == 6 * 6 + 2
    preds = load_predictions(str(tmp_path / "pred3.npz"))
    assert preds.meta["threshold"] == 0.8
    steps = [p.steps for p in preds.scans]
    assert steps[0] < steps[1] and steps[1] == sets.scan_steps(0).stop - sets.scan_steps(0).start
    for p in preds.scans:
        assert p.probs.shape == (4, *sets.labels[0].shape) and p.truth is not None
        thin = np.isin(p.label, (2, 3))
        assert (p.probs.astype(np.float32).max(axis=0)[thin] > 0.8 - 1e-3).all()
        assert np.allclose(p.probs.astype(np.float32).sum(axis=0), 1.0, atol=1e-2)
    img = nib.load(str(tmp_path / "nii" / "000_Sph0_o0_t48_labels.nii.gz"))
    assert img.shape == tuple(reversed(sets.labels[0].shape))
    assert np.allclose(img.affine[:3, 3], sets.labels[0].origin_mm[::-1])
    rows = _ok(run_less("render", "pred3.npz", "-o", "figs", "--scan", "1", "--format", "jsonl"))
    assert [r["kind"] for r in rows] == ["panels", "strip"]
    assert all((tmp_path / r["figure"]).stat().st_size > 10_000 for r in rows)
    mesh = _ok(run_less("mesh", "pred3.npz", "--truth", "--classes", "inclusion", "-o", "inc.glb", "--format",
                        "jsonl"))
    assert mesh[0]["class"] == "inclusion" and mesh[0]["volume_mm3"] > 0


def test_resume_finetune_and_errors(tmp_path, run_less, sets):
    from lesscli.io.scans import load_scans

    train = load_scans(str(tmp_path / "train.npz"))
    make_representation(str(tmp_path / "rep.pt"), train)
    common = ["--dim", "2", "--lr", "1e-2", "--device", "cpu", "--set", "image.width=8", "--set",
              "image.patch_px=8", "--format", "jsonl"]
    (first,) = _ok(run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "a.pt", "--epochs", "1",
                            *common, env=ONE_THREAD))
    (again,) = _ok(run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "a.pt", "--epochs", "2",
                            "--resume", *common, env=ONE_THREAD))
    assert len((tmp_path / "a.log.jsonl").read_text().splitlines()) == 2 and again["epochs"] == 2
    (tuned,) = _ok(run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "b.pt", "--epochs", "1",
                            "--finetune", *common, env=ONE_THREAD))
    assert not tuned["frozen"] and tuned["trainable_parameters"] > first["trainable_parameters"]
    # image.encoder_lr: the representation's own learning rate, the decoder's --lr unchanged
    rep = encoder_state(torch.load(tmp_path / "rep.pt", weights_only=False)["model_state"])
    moved = {}
    for name, extra in (("b.pt", []), ("slow.pt", ["--set", "image.encoder_lr=1e-9"])):
        if extra:
            _ok(run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", name, "--epochs", "1",
                         "--finetune", *extra, *common, env=ONE_THREAD))
        state = torch.load(tmp_path / name, weights_only=False)["model_state"]
        moved[name] = max(float((v - rep[k]).abs().max()) for k, v in encoder_state(state).items())
    assert moved["b.pt"] > 1e-4 and moved["slow.pt"] < 1e-7
    # a representation is not an imaging model
    proc = run_less("image", "predict", "rep.pt", "test.npz", "-o", "p.npz", "--device", "cpu")
    assert (proc.returncode == 1 and b"not an imaging checkpoint" in proc.stderr
            and not (tmp_path / "p.npz").exists())
    proc = run_less("image", "predict", "a.pt", "test.npz", "-o", "p.npz", "--steps", "2", "--every", "3")
    assert proc.returncode == 2
    unlabeled = learnable_scanset(2, 5)
    unlabeled.scan_label[:] = -1
    unlabeled.labels = []
    save_scans(str(tmp_path / "nolabels.npz"), unlabeled)
    proc = run_less("image", "fit", "nolabels.npz", "--rep", "rep.pt", "-o", "c.pt", "--epochs", "1", *common)
    assert (proc.returncode == 1 and b"nolabels.npz: scan 0" in proc.stderr
            and not (tmp_path / "c.pt").exists())
    proc = run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "d.pt", "--select", "dice", *common)
    assert proc.returncode == 2 and b"--select" in proc.stderr
    proc = run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "d.pt", "--set",
                    "image.encoder_lr=3e-3", *common)           # a rate for a frozen representation
    assert (proc.returncode == 2 and b"image.encoder_lr" in proc.stderr and b"--finetune" in proc.stderr
            and not (tmp_path / "d.pt").exists())
    proc = run_less("image", "fit", "train.npz", "--rep", "rep.pt", "-o", "d.pt", "--set",
                    "loss.alpha_power=5", *common)
    assert proc.returncode == 2 and b"loss.alpha_power" in proc.stderr and not (tmp_path / "d.pt").exists()
    assert proc.stderr.decode().strip().splitlines()[-1] == ("Error: Invalid value for '--set': 5.0: "
                                                             # a usage error
                                                             "loss.alpha_power must be in [0, 2]")


@pytest.mark.parametrize("key,value,ok", [
    ("image.patch_px", 4, False), ("image.patch_px", 8, True), ("image.patch_px", 12, False),
    ("image.patch_px", 64, True),           # a 4-pixel patch would be the first feature map itself
    ("loss.dice_per", "batch", True), ("loss.dice_per", "scan", True), ("loss.dice_per", "voxel", False),
    ("image.encoder_lr", None, True), ("image.encoder_lr", 3e-3, True), ("image.encoder_lr", 0.0, False)])
def test_image_fit_settings_are_checked(key, value, ok):
    from lesscli.errors import LessError
    from lesscli.train.image_fit import ImageFitConfig, check_config

    cfg = ImageFitConfig()
    cfg.image.finetune = key == "image.encoder_lr"
    section, name = key.split(".")
    setattr(getattr(cfg, section), name, value)
    if ok:
        assert check_config(cfg) is cfg
    else:
        with pytest.raises(LessError, match=f"{key} = {value!r} is invalid: must be "):
            check_config(cfg)


def test_encoder_lr_needs_finetune():
    """An encoder learning rate for a frozen representation would be ignored: it is refused instead."""
    from lesscli.errors import LessError
    from lesscli.train.image_fit import ImageFitConfig, check_config

    cfg = ImageFitConfig()
    cfg.image.encoder_lr = 3e-3
    with pytest.raises(LessError, match="encoder_lr = 0.003 is invalid: must be unset unless --finetune"):
        check_config(cfg)
