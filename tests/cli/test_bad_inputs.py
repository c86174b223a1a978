"""Every bad input gets one clear answer: a corpus of broken files generated here, run through the CLI.

Each case asserts exit status 1, exactly one stderr line that names the file, no traceback (nor the
catch-all "run with -v" line that marks an unforeseen exception), nothing on stdout and nothing
written (no output, no temporary ``.part`` file). The commands run in-process through
``lesscli.cli.main.main``, the same entry the console script calls; a few subprocess cases in
test_cli_contract prove the script itself.
"""

from __future__ import annotations

import io
import json
import os
import struct
import sys

import numpy as np
import pytest
import torch
from factories import random_scanset
from imaging_factory import learnable_scanset, make_representation

from lesscli.cli.main import main
from lesscli.errors import DataError
from lesscli.infer.live import parse_live_line
from lesscli.io.checkpoint import FORMAT
from lesscli.io.predictions import PredictionSet, ScanPrediction, save_predictions
from lesscli.io.scans import save_scans, to_arrays

# ---------------------------------------------------------------------------------------------- harness


def fails_clearly(capsys, folder, args, name) -> str:
    """Run ``less ARGS`` in-process; check the failure contract; return the stderr line."""
    before = set(os.listdir(folder))
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in args])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert exc.value.code == 1, err
    assert len(lines) == 1 and lines[0].startswith("less: error: "), err
    assert str(name) in lines[0], err
    assert "Traceback" not in err and "run with -v" not in err, err
    assert out == ""
    assert set(os.listdir(folder)) == before, "an output or temporary file was left behind"
    return lines[0]


def _meta(**change):
    def mutate(a):
        meta = json.loads(str(a["meta"]))
        meta.update(change)
        a["meta"] = np.array(json.dumps(meta))
    return mutate


def _drop_meta(key):
    def mutate(a):
        meta = json.loads(str(a["meta"]))
        meta.pop(key)
        a["meta"] = np.array(json.dumps(meta))
    return mutate


def _sensor(**change):
    def mutate(a):
        meta = json.loads(str(a["meta"]))
        meta["sensor"] = {**meta["sensor"], **change}
        a["meta"] = np.array(json.dumps(meta))
    return mutate


def _put(key, make):
    """Replace ``key`` by ``make(old value)``."""
    return lambda a: a.__setitem__(key, make(a[key]))


def _pop(key):
    return lambda a: a.pop(key)


def _at(key, index, value, dtype=None):
    def mutate(a):
        arr = a[key].astype(dtype or a[key].dtype)
        arr[index] = value
        a[key] = arr
    return mutate


def _swap_first(arr):
    out = arr.copy()
    out[[1, 2]] = out[[2, 1]]
    return out


# ---------------------------------------------------------------------------------------------- scan sets

SCAN_CASES = {
    **{f"missing {k}": _pop(k) for k in ("pose", "force", "traj_offsets", "traj_scan", "scan_insert", "meta",
                                          "label_shape", "label_data", "label_origin_mm",
                                          "label_spacing_mm")},
    "meta not JSON": lambda a: a.__setitem__("meta", np.array("{not json")),
    "meta a JSON list": lambda a: a.__setitem__("meta", np.array("[1, 2]")),
    "meta a JSON number": lambda a: a.__setitem__("meta", np.array("3")),
    "meta a JSON string": lambda a: a.__setitem__("meta", np.array('"less.scans"')),
    "meta null": lambda a: a.__setitem__("meta", np.array("null")),
    "meta an array of strings": _put("meta", lambda m: np.array([str(m)])),
    "meta a number array": lambda a: a.__setitem__("meta", np.array(3.0)),
    "schema of a prediction": _meta(schema="less.pred"),
    "schema missing": _drop_meta("schema"),
    "version 2": _meta(version=2),
    "version a string": _meta(version="1"),
    "history a dict": _meta(history={"a": 1}),
    "sensor a string": _meta(sensor="xela"),
    "sensor a list": _meta(sensor=[30]),
    "sensor.taxels a string": _sensor(taxels="30"),
    "sensor.taxels zero": _sensor(taxels=0),
    "sensor.taxels fractional": _sensor(taxels=30.5),
    "sensor.taxels disagrees with force": _sensor(taxels=31),
    "units a string": _meta(units="SI"),
    "sample_rate_hz a string": _meta(sample_rate_hz="100"),
    "sample_rate_hz negative": _meta(sample_rate_hz=-5),
    "sample_rate_hz zero": _meta(sample_rate_hz=0),
    "pose as strings": _put("pose", lambda p: p.astype(str)),
    "pose complex": _put("pose", lambda p: p.astype(complex)),
    "pose flat": _put("pose", lambda p: p.reshape(-1)),
    "pose 5 columns": _put("pose", lambda p: p[:, :5]),
    "pose 3-D": _put("pose", lambda p: p[:, :, None]),
    "pose NaN": _at("pose", (2, 0), np.nan),
    "pose inf": _at("pose", (1, 3), np.inf),
    "pose beyond float32": _at("pose", (1, 0), 1e39, np.float64),
    "force as strings": _put("force", lambda f: f.astype(str)),
    "force flat per step": _put("force", lambda f: f.reshape(len(f), -1)),
    "force 2 axes": _put("force", lambda f: f[:, :, :2]),
    "force NaN": _at("force", (4, 0, 2), np.nan),
    "force -inf": _at("force", (0, 5, 1), -np.inf),
    "force one step short": _put("force", lambda f: f[:-1]),
    "force beyond float32": _at("force", (3, 0, 0), -1e40, np.float64),
    "force 29 taxels": _put("force", lambda f: f[:, :29]),
    "time_s NaN": _at("time_s", 3, np.nan),
    "time_s inf": _at("time_s", 0, np.inf),
    "time_s strings": _put("time_s", lambda t: t.astype(str)),
    "time_s 2-D": _put("time_s", lambda t: t[:, None]),
    "time_s short": _put("time_s", lambda t: t[:-1]),
    "traj_offsets fractional": _put("traj_offsets", lambda o: o + 0.5),
    "traj_offsets strings": _put("traj_offsets", lambda o: o.astype(str)),
    "traj_offsets 2-D": _put("traj_offsets", lambda o: o[:, None]),
    "traj_offsets not from 0": _put("traj_offsets", lambda o: o + 1),
    "traj_offsets end early": _at("traj_offsets", -1, 1),
    "traj_offsets decreasing": _put("traj_offsets", _swap_first),
    "traj_offsets empty": _put("traj_offsets", lambda o: o[:0]),
    "traj_scan short": _put("traj_scan", lambda t: t[:-1]),
    "traj_scan decreasing": _put("traj_scan", lambda t: t[::-1]),
    "traj_scan negative": _at("traj_scan", 0, -1),
    "traj_scan past the scans": _put("traj_scan", lambda t: t + 5),
    "traj_scan strings": _put("traj_scan", lambda t: t.astype(str)),
    "traj_scan fractional": _put("traj_scan", lambda t: t + 0.25),
    "scan_insert numbers": _put("scan_insert", lambda s: np.arange(len(s))),
    "scan_insert 2-D": _put("scan_insert", lambda s: s[None]),
    "traj_scan past a shortened scan_insert": _put("scan_insert", lambda s: s[:1]),
    "scan_orientation 9": _at("scan_orientation", 0, 9),
    "scan_orientation -1": _at("scan_orientation", 1, -1),
    "scan_orientation strings": _put("scan_orientation", lambda s: s.astype(str)),
    "scan_orientation short": _put("scan_orientation", lambda s: s[:1]),
    "scan_orientation fractional": _put("scan_orientation", lambda s: s + 0.5),
    "scan_label -2": _at("scan_label", 0, -2),
    "scan_label past the volumes": _at("scan_label", 1, 5),
    "scan_label strings": _put("scan_label", lambda s: s.astype(str)),
    "scan_label short": _put("scan_label", lambda s: s[:1]),
    "label_shape negative": _put("label_shape", lambda s: s * np.array([-1, -1, 1])),
    "label_shape zero": _at("label_shape", (0, 0), 0),
    "label_shape 2 columns": _put("label_shape", lambda s: s[:, :2]),
    "label_shape strings": _put("label_shape", lambda s: s.astype(str)),
    "label_shape fractional": _put("label_shape", lambda s: s + 0.5),
    "label_data shorter than label_shape says": _put("label_shape", lambda s: np.concatenate([s, s[:1]])),
    "label_data code 9": _at("label_data", 7, 9),
    "label_data code -1": _at("label_data", 3, -1, np.int16),
    "label_data fractional": _at("label_data", 0, 1.5, np.float32),
    "label_data NaN": _at("label_data", 0, np.nan, np.float32),
    "label_data strings": _put("label_data", lambda d: d.astype(str)),
    "label_data 2-D": _put("label_data", lambda d: d[None]),
    "label_data short": _put("label_data", lambda d: d[:-1]),
    "label_origin_mm NaN": _at("label_origin_mm", (0, 1), np.nan),
    "label_origin_mm strings": _put("label_origin_mm", lambda o: o.astype(str)),
    "label_origin_mm one row": _put("label_origin_mm", lambda o: o[:1]),
    "label_spacing_mm zero": _at("label_spacing_mm", (1, 2), 0.0),
    "label_spacing_mm negative": _at("label_spacing_mm", (0, 0), -1.0),
    "label_spacing_mm NaN": _at("label_spacing_mm", (0, 1), np.nan),
    "label_spacing_mm strings": _put("label_spacing_mm", lambda o: o.astype(str)),
    "label_spacing_mm 2 columns": _put("label_spacing_mm", lambda o: o[:, :2]),
    "label_name one short": _put("label_name", lambda n: n[:1]),
    "label_name numbers": _put("label_name", lambda n: np.arange(len(n))),
    "traj_target_force_n strings": _put("traj_target_force_n", lambda t: np.array(["abc"] * len(t))),
    "traj_target_force_n short": _put("traj_target_force_n", lambda t: t[:-1]),
    "traj_primitive numbers": _put("traj_primitive", lambda t: np.zeros(len(t))),
}


def _key_of(case: str) -> str:
    """The key a case breaks, which the message must name: 'pose NaN' -> pose, 'missing meta' -> meta."""
    words = case.split()
    return (words[1] if words[0] == "missing" else words[0]).split(".")[0]


def _raw_npz(path, arrays):
    np.savez(path, **arrays)
    return path


def _npy_file(path):
    with open(path, "wb") as fh:
        np.save(fh, np.zeros(3))
    return path


SCAN_FILE_CASES = {
    "garbage bytes": lambda p: (p.write_bytes(b"\x00garbage that is not a zip" * 4), p)[1],
    "empty file": lambda p: (p.write_bytes(b""), p)[1],
    "a .npy array": _npy_file,
    "a JSON text file": lambda p: (p.write_text('{"pose": [1, 2]}'), p)[1],
    "truncated archive": lambda p: (save_scans(str(p), random_scanset()), p.write_bytes(p.read_bytes()[:300]),
                                    p)[2],
    "pickled object": lambda p: _raw_npz(p,
                                         {**to_arrays(random_scanset()),
                                          "force": np.array([{"a": 1}], object)}),
    "missing file": lambda p: p,
    "folder without shards": lambda p: (p.mkdir(), p)[1],
    "folder with one bad shard": lambda p: (p.mkdir(), save_scans(str(p / "a.npz"), random_scanset()),
                                            (p / "b.npz").write_bytes(b"junk"), p)[3],
}


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("case", sorted(SCAN_CASES))
def test_bad_scan_set(capsys, in_tmp, case):
    arrays = to_arrays(random_scanset())
    SCAN_CASES[case](arrays)
    _raw_npz(in_tmp / "bad.npz", arrays)
    line = fails_clearly(capsys, in_tmp, ["subsample", "bad.npz", "--every", "2", "-o", "out.npz"], "bad.npz")
    assert _key_of(case) in line


@pytest.mark.parametrize("case", sorted(SCAN_FILE_CASES))
def test_bad_scan_file(capsys, in_tmp, case):
    path = SCAN_FILE_CASES[case](in_tmp / "bad.npz")
    line = fails_clearly(capsys, in_tmp, ["subsample", path.name, "-o", "out.npz"], "bad.npz")
    assert "allow_pickle" not in line


def test_garbage_says_what_the_file_is_not(capsys, in_tmp):
    (in_tmp / "x.npz").write_bytes(b"hello world, not an archive")
    line = fails_clearly(capsys, in_tmp, ["info", "x.npz"], "x.npz")
    assert "not a less.scans/1 scan set or less.pred/1 prediction file: not a .npz archive" in line


# ---------------------------------------------------------------------------------------------- predictions

def _prediction_arrays(tmp_path) -> dict:
    rng = np.random.default_rng(0)
    scans = []
    for i in range(2):
        probs = rng.dirichlet(np.ones(4), size=(3, 5, 6)).transpose(3, 0, 1, 2).astype(np.float32)
        truth = rng.integers(0, 4, (3, 5, 6)).astype(np.uint8) if i == 0 else None
        scans.append(ScanPrediction(probs, np.zeros(3), np.ones(3), truth, f"St1{i}C5", i, 10))
    save_predictions(str(tmp_path / "good_pred.npz"), PredictionSet(scans, {"dim": 3}))
    with np.load(tmp_path / "good_pred.npz") as npz:
        arrays = dict(npz)
    os.remove(tmp_path / "good_pred.npz")
    return arrays


PRED_KEYS = ("probs_data", "probs_shape", "label_data", "entropy_data", "truth_data", "has_truth",
             "origin_mm", "spacing_mm", "scan_insert", "scan_orientation", "scan_steps", "meta")
PRED_CASES = {
    **{f"missing {k}": _pop(k) for k in PRED_KEYS},
    "meta a JSON list": lambda a: a.__setitem__("meta", np.array("[]")),
    "meta not JSON": lambda a: a.__setitem__("meta", np.array("{")),
    "schema of a scan set": _meta(schema="less.scans"),
    "version 2": _meta(version=2),
    "probs_shape negative": _at("probs_shape", (0, 1), -3),
    "probs_shape 3 classes": _at("probs_shape", (1, 0), 3),
    "probs_shape 3 columns": _put("probs_shape", lambda s: s[:, 1:]),
    "probs_shape strings": _put("probs_shape", lambda s: s.astype(str)),
    "probs_data NaN": _at("probs_data", 5, np.nan),
    "probs_data negative": _at("probs_data", 5, -0.5),
    "probs_data above 1": _at("probs_data", 5, 2.0),
    "probs_data strings": _put("probs_data", lambda p: p.astype(str)),
    "probs_data short": _put("probs_data", lambda p: p[:-1]),
    "probs_data not summing to 1": _put("probs_data", lambda p: np.full_like(p, 0.1)),
    "label_data code 9": _at("label_data", 2, 9),
    "label_data short": _put("label_data", lambda d: d[:-1]),
    "label_data strings": _put("label_data", lambda d: d.astype(str)),
    "entropy_data NaN": _at("entropy_data", 0, np.nan),
    "entropy_data negative": _at("entropy_data", 0, -1.0),
    "entropy_data short": _put("entropy_data", lambda d: d[:-1]),
    "truth_data code 9": _at("truth_data", 1, 9),
    "truth_data short": _put("truth_data", lambda d: d[:-1]),
    "has_truth short": _put("has_truth", lambda h: h[:1]),
    "has_truth strings": _put("has_truth", lambda h: h.astype(str)),
    "has_truth 2": _at("has_truth", 1, 2, np.int64),
    "origin_mm NaN": _at("origin_mm", (0, 0), np.nan),
    "origin_mm one row": _put("origin_mm", lambda o: o[:1]),
    "spacing_mm NaN": _at("spacing_mm", (1, 1), np.nan),
    "spacing_mm zero": _at("spacing_mm", (0, 2), 0.0),
    "spacing_mm negative": _at("spacing_mm", (0, 0), -1.0),
    "spacing_mm strings": _put("spacing_mm", lambda s: s.astype(str)),
    "spacing_mm one row": _put("spacing_mm", lambda s: s[:1]),
    "scan_insert numbers": _put("scan_insert", lambda s: np.arange(len(s))),
    "scan_insert one short": _put("scan_insert", lambda s: s[:1]),
    "scan_orientation strings": _put("scan_orientation", lambda s: s.astype(str)),
    "scan_orientation one short": _put("scan_orientation", lambda s: s[:1]),
    "scan_steps fractional": _put("scan_steps", lambda s: s + 0.5),
    "scan_steps one short": _put("scan_steps", lambda s: s[:1]),
    # the optional keys: which scan each image is, where the pad touched
    "scan_index decreasing": lambda a: a.__setitem__("scan_index", np.array([1, 0])),
    "scan_index negative": lambda a: a.__setitem__("scan_index", np.array([-1, 0])),
    "scan_index one short": lambda a: a.__setitem__("scan_index", np.array([0])),
    "scan_index fractional": lambda a: a.__setitem__("scan_index", np.array([0.5, 1.0])),
    "touch_count negative": lambda a: a.update(touch_count=np.array([-1, 1]), touch_xy_mm=np.zeros((0, 2))),
    "touch_count one short": lambda a: a.update(touch_count=np.array([1]), touch_xy_mm=np.zeros((1, 2))),
    "touch_count without touch_xy_mm": lambda a: a.__setitem__("touch_count", np.array([0, 0])),
    "touch_xy_mm without touch_count": lambda a: a.__setitem__("touch_xy_mm", np.zeros((0, 2))),
    "touch_xy_mm NaN": lambda a: a.update(touch_count=np.array([1, 1]),
                                          touch_xy_mm=np.array([[0, np.nan], [1, 1]])),
    "touch_xy_mm fewer than counted": lambda a: a.update(touch_count=np.array([2, 1]),
                                                         touch_xy_mm=np.zeros((2, 2))),
    "touch_xy_mm 3 columns": lambda a: a.update(touch_count=np.array([1, 0]), touch_xy_mm=np.zeros((1, 3))),
}


@pytest.mark.parametrize("case", sorted(PRED_CASES))
def test_bad_prediction(capsys, in_tmp, case):
    arrays = _prediction_arrays(in_tmp)
    PRED_CASES[case](arrays)
    _raw_npz(in_tmp / "pred.npz", arrays)
    line = fails_clearly(capsys, in_tmp, ["render", "pred.npz", "-o", "figs"], "pred.npz")
    assert _key_of(case) in line


def test_a_prediction_with_nan_is_not_written(tmp_path):
    probs = np.full((4, 2, 3, 3), 0.25, np.float32)
    probs[:, 0, 1, 1] = np.nan
    with pytest.raises(DataError, match=r"out.npz: 'probs_data' has NaN or inf"):
        save_predictions(str(tmp_path / "out.npz"),
                         PredictionSet([ScanPrediction(probs, np.zeros(3), np.ones(3))]))
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("make", [
    lambda p: (p.write_bytes(b"\x89PNG not a prediction"), p)[1],
    lambda p: (p.write_bytes(b""), p)[1],
    lambda p: (save_scans(str(p), random_scanset()), p)[1],
], ids=["garbage", "empty", "a scan set"])
def test_bad_prediction_file(capsys, in_tmp, make):
    make(in_tmp / "pred.npz")
    fails_clearly(capsys, in_tmp, ["metrics", "pred.npz"], "pred.npz")


# ---------------------------------------------------------------------------------------------- label NIfTI

def _nifti(path, data, affine=None):
    import nibabel as nib

    img = nib.Nifti1Image(np.asarray(data), None)
    img.set_sform(np.eye(4) if affine is None else affine, code=1)    # sform only: nibabel keeps it as given
    nib.save(img, str(path))
    return path


def _patch(path, offset: int, raw: bytes):
    data = bytearray(path.read_bytes())
    data[offset:offset + len(raw)] = raw
    path.write_bytes(bytes(data))
    return path


SROW_X_OFFSET = 280   # NIfTI-1 header: first sform row (nibabel refuses to write a NaN affine itself)
_VOL = np.zeros((6, 5, 4), np.uint8)
_ROTATED = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
NIFTI_CASES = {
    "2-D": lambda p: _nifti(p, _VOL[:, :, 0]),
    "4-D": lambda p: _nifti(p, _VOL[..., None]),
    "NaN": lambda p: _nifti(p, np.where(_VOL == 0, np.nan, 1).astype(np.float32)),
    "code 9": lambda p: _nifti(p, _VOL + 9),
    "code -1": lambda p: _nifti(p, _VOL.astype(np.int16) - 1),
    "fractional": lambda p: _nifti(p, _VOL.astype(np.float32) + 0.5),
    "rotated affine": lambda p: _nifti(p, _VOL, _ROTATED),
    "zero voxel size": lambda p: _nifti(p, _VOL, np.diag([1.0, 0.0, 1.0, 1.0])),
    "NaN affine": lambda p: _patch(_nifti(p, _VOL), SROW_X_OFFSET, struct.pack("<f", np.nan)),
    "garbage bytes": lambda p: (p.write_bytes(b"not a nifti" * 40), p)[1],
    "empty file": lambda p: (p.write_bytes(b""), p)[1],
    "missing file": lambda p: p,
}


@pytest.mark.parametrize("case", sorted(NIFTI_CASES))
def test_bad_label_volume(capsys, in_tmp, case):
    NIFTI_CASES[case](in_tmp / "labels.nii")
    fails_clearly(capsys, in_tmp, ["mesh", "labels.nii", "-o", "out.stl"], "labels.nii")


# ---------------------------------------------------------------------------------------------- checkpoints

def _ckpt(**change):
    good = {"format": FORMAT, "version": 1, "model_state": {"w": torch.zeros(2)}, "norm_stats": {},
            "config": {}, "history": [], "extra": {}}
    return {**good, **change}


CKPT_CASES = {
    "garbage bytes": lambda p: p.write_bytes(b"PK\x03\x04 broken zip"),
    "empty file": lambda p: p.write_bytes(b""),
    "a tensor": lambda p: torch.save(torch.zeros(3), p),
    "another format": lambda p: torch.save(_ckpt(format="other"), p),
    "version 2": lambda p: torch.save(_ckpt(version=2), p),
    "version a string": lambda p: torch.save(_ckpt(version="1"), p),
    "config a list": lambda p: torch.save(_ckpt(config=[1]), p),
    "model_state a list": lambda p: torch.save(_ckpt(model_state=[1]), p),
    "model_state not tensors": lambda p: torch.save(_ckpt(model_state={"w": "x"}), p),
    "history a dict": lambda p: torch.save(_ckpt(history={}), p),
    "norm_stats NaN": lambda p: torch.save(_ckpt(norm_stats={"force_mean": [float("nan")],
                                                             "force_std": [1.0]}), p),
    "norm_stats zero scale": lambda p: torch.save(_ckpt(norm_stats={"force_mean": [0.0], "force_std": [0.0]}),
                                                  p),
    "norm_stats lengths differ": lambda p: torch.save(_ckpt(norm_stats={"force_mean": [0.0],
                                                                        "force_std": []}), p),
    "norm_stats without std": lambda p: torch.save(_ckpt(norm_stats={"force_mean": [0.0]}), p),
    "not an imager": lambda p: torch.save(_ckpt(), p),
    "a representation": lambda p: make_representation(str(p), random_scanset(), dim=8),
    "weights NaN": lambda p: torch.save(_ckpt(model_state={"w": torch.tensor([0.0, float("nan")])}), p),
    "weights inf": lambda p: torch.save(_ckpt(model_state={"w": torch.tensor([float("-inf")])}), p),
}


def _imager_with(models, change):
    def make(path):
        ckpt = torch.load(models / "imager.pt", weights_only=True)
        change(ckpt)
        torch.save(ckpt, path)
    return make


IMAGER_CASES = {
    "config image a string": lambda c: c["config"].__setitem__("image", "x"),
    "config image.dim a string": lambda c: c["config"]["image"].__setitem__("dim", "three"),
    "config image.threshold a string": lambda c: c["config"]["image"].__setitem__("threshold", "hi"),
    "config image.threshold 2": lambda c: c["config"]["image"].__setitem__("threshold", 2.0),
    "config image.min_volume_mm3 negative":
        lambda c: c["config"]["image"].__setitem__("min_volume_mm3", -5.0),
    "config image.min_volume_mm3 a string":
        lambda c: c["config"]["image"].__setitem__("min_volume_mm3", "big"),
    "config image.smooth_mm negative": lambda c: c["config"]["image"].__setitem__("smooth_mm", -1.0),
    "config image.smooth_mm a string": lambda c: c["config"]["image"].__setitem__("smooth_mm", "wide"),
    "config grid without shape": lambda c: c["config"]["grid"].pop("shape"),
    "config encoder unknown": lambda c: c["config"]["encoder"].__setitem__("name", "lesss"),
    "config encoder.dim a string": lambda c: c["config"]["encoder"].__setitem__("dim", "a"),
    "config decoder a list": lambda c: c["config"].__setitem__("decoder", [1]),
    "weights of another shape": lambda c: c["model_state"].__setitem__(next(iter(c["model_state"])),
                                                                       torch.zeros(1)),
    "weights NaN (a diverged run)": lambda c: c["model_state"].__setitem__(
        next(k for k, v in c["model_state"].items() if v.is_floating_point()),
        torch.full_like(next(v for v in c["model_state"].values() if v.is_floating_point()), float("nan"))),
}


@pytest.mark.parametrize("command", ["image predict", "stream", "guide"])
@pytest.mark.parametrize("case", sorted(IMAGER_CASES))
def test_bad_imager_checkpoint(capsys, in_tmp, models, case, command):
    save_scans("data.npz", random_scanset())
    _imager_with(models, IMAGER_CASES[case])(in_tmp / "model.pt")
    args = {"image predict": ["image", "predict", "model.pt", "data.npz", "-o", "pred.npz"],
            "stream": ["stream", "model.pt", "data.npz"], "guide": ["guide", "model.pt", "data.npz"]}[command]
    line = fails_clearly(capsys, in_tmp, args, "model.pt")
    # the checkpoint is to blame, not its output
    assert "pred.npz" not in line and "data.npz" not in line


def test_a_live_pose_of_true_and_false_is_named_through_a_pipe(run_less, models):
    good = {"t": 0.0, "pose": [0.0] * 6, "force": GOOD_FORCE}
    lines = [good, {**good, "t": 0.1, "pose": [True, 0, 0, 0, 0, 0]}, {**good, "t": 0.2}]
    text = "".join(json.dumps(line) + "\n" for line in lines).encode()
    proc = run_less("stream", models / "imager.pt", "-", "--on-error", "stop", input=text)
    # the latency summary of the one good sample, then:
    err = proc.stderr.decode().strip().splitlines()
    assert proc.returncode == 1 and err[-1] == ("less: error: -: line 2: 'pose' holds true/false; it must be "
                                                "a list of numbers; stopping (--on-error stop)"), err
    assert sum("error" in line for line in err) == 1 and proc.stdout.decode().count("\n") <= 1


@pytest.mark.parametrize("command", ["image predict", "stream", "guide", "noise-sweep"])
def test_data_with_other_taxels_than_the_model(capsys, in_tmp, models, command):
    scans = random_scanset()
    scans.force, scans.meta = scans.force[:, :20], {**scans.meta,
                                                    "sensor": {**scans.meta["sensor"], "taxels": 20}}
    save_scans("data.npz", scans)
    imager = models / "imager.pt"
    args = {"image predict": ["image", "predict", imager, "data.npz", "-o", "pred.npz"],
            "stream": ["stream", imager, "data.npz"], "guide": ["guide", imager, "data.npz"],
            "noise-sweep": ["noise-sweep", imager, "data.npz", "--pos-mm", "0", "--ang-rad", "0"]}[command]
    line = fails_clearly(capsys, in_tmp, args, "data.npz")
    assert "20 taxels x 3 = 60 features" in line


@pytest.mark.parametrize("case", sorted(CKPT_CASES))
def test_bad_checkpoint(capsys, in_tmp, case):
    save_scans("data.npz", random_scanset())
    CKPT_CASES[case](in_tmp / "model.pt")
    fails_clearly(capsys, in_tmp, ["image", "predict", "model.pt", "data.npz", "-o", "pred.npz"], "model.pt")


def test_missing_checkpoint(capsys, in_tmp):
    save_scans("data.npz", random_scanset())
    fails_clearly(capsys, in_tmp, ["image", "predict", "model.pt", "data.npz", "-o", "pred.npz"], "model.pt")


# ---------------------------------------------------------------------------------------------- every reader

@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """A representation and a one-epoch imager on a tiny learnable set (files in a module folder)."""
    folder = tmp_path_factory.mktemp("models")
    scans = learnable_scanset(2, 0, steps_per_traj=4, traj_per_scan=4)
    save_scans(str(folder / "train.npz"), scans)
    make_representation(str(folder / "rep.pt"), scans, dim=8)
    with _no_exit():
        main(["-q", "image", "fit", str(folder / "train.npz"), "--rep", str(folder / "rep.pt"), "-o",
              str(folder / "imager.pt"), "--epochs", "1", "--format", "jsonl"])
    return folder


class _no_exit:
    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        assert kind is None, exc


BAD_DATA = {"time_s NaN": SCAN_CASES["time_s NaN"], "meta a JSON list": SCAN_CASES["meta a JSON list"],
            "pose as strings": SCAN_CASES["pose as strings"]}
READERS = {
    "info": lambda m: ["info", "bad.npz"],
    "split": lambda m: ["split", "bad.npz", "-o", "parts"],
    "concat": lambda m: ["concat", "bad.npz", "bad.npz", "-o", "both.npz"],
    "pretrain": lambda m: ["pretrain", "bad.npz", "-o", "rep.pt", "--epochs", "1"],
    "image fit": lambda m: ["image", "fit", "bad.npz", "--rep", m / "rep.pt", "-o", "im.pt", "--epochs", "1"],
    "image fit forcemap": lambda m: ["image", "fit", "bad.npz", "--model", "forcemap", "-o", "fm.pt"],
    "image predict": lambda m: ["image", "predict", m / "imager.pt", "bad.npz", "-o", "pred.npz"],
    "noise-sweep": lambda m: ["noise-sweep", m / "imager.pt", "bad.npz", "--pos-mm", "0", "--ang-rad", "0"],
    "guide": lambda m: ["guide", m / "imager.pt", "bad.npz"],
    "stream": lambda m: ["stream", m / "imager.pt", "bad.npz"],
}


@pytest.mark.parametrize("bad", sorted(BAD_DATA))
@pytest.mark.parametrize("command", sorted(READERS))
def test_every_command_reads_through_the_validator(capsys, in_tmp, models, command, bad):
    arrays = to_arrays(random_scanset())
    BAD_DATA[bad](arrays)
    _raw_npz(in_tmp / "bad.npz", arrays)
    fails_clearly(capsys, in_tmp, READERS[command](models), "bad.npz")


# ---------------------------------------------------------------------------------------------- output paths

OUTPUT_CASES = {
    "subsample into a missing folder": (["subsample", "good.npz", "-o", "nodir/x.npz"], "nodir/x.npz"),
    "subsample onto a folder": (["subsample", "good.npz", "-o", "adir"], "adir"),
    "split into a file": (["split", "good.npz", "-o", "afile.txt"], "afile.txt"),
    "concat onto a folder": (["concat", "good.npz", "good.npz", "-o", "adir"], "adir"),
    "pretrain into a missing folder": (["pretrain", "good.npz", "-o", "nodir/rep.pt"], "nodir/rep.pt"),
    "predict onto a folder": (["image", "predict", "m.pt", "good.npz", "-o", "adir"], "adir"),
    "predict --nifti into a file": (["image", "predict", "m.pt", "good.npz", "-o", "p.npz", "--nifti",
                                     "afile.txt"],
                                    "afile.txt"),
    "render into a file": (["render", "p.npz", "-o", "afile.txt"], "afile.txt"),
    "noise-sweep --plot in a missing folder": (["noise-sweep", "m.pt", "good.npz", "--plot", "nodir/n.png"],
                                               "nodir/n.png"),
    "guide --plot onto a folder": (["guide", "m.pt", "good.npz", "--plot", "adir"], "adir"),
    "phantom into a file": (["phantom", "--set", "single", "-o", "afile.txt"], "afile.txt"),
    "pose track into a missing folder": (["pose", "track", "frames", "--camera", "c.json", "-o",
                                          "nodir/p.jsonl"],
                                         "nodir/p.jsonl"),
    "mri-label --synth into a missing folder": (["mri-label", "--synth", "St12C13", "-o", "nodir/s.nii.gz"],
                                                "nodir/s.nii.gz"),
    "stream -o into a file": (["stream", "m.pt", "good.npz", "-o", "afile.txt"], "afile.txt"),
}


@pytest.mark.parametrize("case", sorted(OUTPUT_CASES))
def test_output_path_is_checked_before_any_work(capsys, in_tmp, case):
    save_scans("good.npz", random_scanset())
    (in_tmp / "adir").mkdir()
    (in_tmp / "afile.txt").write_text("keep me\n")
    args, name = OUTPUT_CASES[case]
    fails_clearly(capsys, in_tmp, args, name)
    assert (in_tmp / "afile.txt").read_text() == "keep me\n" and os.listdir(in_tmp / "adir") == []


# ---------------------------------------------------------------------------------------------- live samples

GOOD_FORCE = [[0.0, 0.0, 1.0]] * 30
LIVE_CASES = {
    "not JSON": ("{pose", "not JSON"),
    "a list": ("[1, 2]", "expected a JSON object"),
    "no pose": (json.dumps({"force": GOOD_FORCE}), "missing 'pose'"),
    "pose of 5": (json.dumps({"pose": [0] * 5, "force": GOOD_FORCE}), "'pose' has 5 values"),
    "pose strings": (json.dumps({"pose": ["a"] * 6, "force": GOOD_FORCE}), "'pose' must be"),
    "pose NaN": (f'{{"pose": [NaN, 0, 0, 0, 0, 0], "force": {json.dumps(GOOD_FORCE)}}}', "finite"),
    "pose 1e308": (json.dumps({"pose": [1e308, 0, 0, 0, 0, 0], "force": GOOD_FORCE}), "beyond float32"),
    "pose empty": (json.dumps({"pose": [], "force": GOOD_FORCE}), "'pose' must be"),
    "force of 89": (json.dumps({"pose": [0] * 6, "force": [0.0] * 89}), "'force' has 89 values"),
    "force ragged": (json.dumps({"pose": [0] * 6, "force": [[0, 0], [0, 0, 0]]}), "'force' must be"),
    "t a string": (json.dumps({"t": "0.1", "pose": [0] * 6, "force": GOOD_FORCE}), "'t' must be"),
    "t true": (json.dumps({"t": True, "pose": [0] * 6, "force": GOOD_FORCE}), "'t' must be"),
    "t back in time": (json.dumps({"t": 0.5, "pose": [0] * 6, "force": GOOD_FORCE}), "goes back in time"),
    "not UTF-8": (b'{"pose": "\xff\xfe"}', "not UTF-8"),
    "pose true": (json.dumps({"pose": [True, 0, 0, 0, 0, 0], "force": GOOD_FORCE}),
                  "'pose' holds true/false"),
    "pose all false": (json.dumps({"pose": [False] * 6, "force": GOOD_FORCE}), "'pose' holds true/false"),
    "force true": (json.dumps({"pose": [0] * 6, "force": [[0, 0, True]] + GOOD_FORCE[1:]}),
                   "'force' holds true/false"),
}


@pytest.mark.parametrize("case", sorted(LIVE_CASES))
def test_bad_live_line(case):
    text, words = LIVE_CASES[case]
    with pytest.raises(ValueError, match=words):
        parse_live_line(text, 90, after_t=1.0)


def test_live_stream_names_the_line_and_stops(capsys, in_tmp, models, monkeypatch):
    good = json.dumps({"t": 1.0, "pose": [0] * 6, "force": GOOD_FORCE}).encode()
    lines = [good, b"\xff\xfe not text",
             json.dumps({"t": 0.5, "pose": [0] * 6, "force": GOOD_FORCE}).encode()]
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"\n".join(lines) + b"\n")))
    with _no_exit():
        main(["stream", str(models / "imager.pt"), "-", "--on-error", "skip", "--emit-every", "100"])
    err = capsys.readouterr().err
    assert "-: line 2: not UTF-8 text" in err and "-: line 3: 't' goes back in time" in err
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"\n".join(lines) + b"\n")))
    with pytest.raises(SystemExit) as exc:
        main(["stream", str(models / "imager.pt"), "-", "--on-error", "stop"])
    assert exc.value.code == 1 and "-: line 2: not UTF-8 text" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- other readers

NOT_UTF8 = b"\xff\xfe\x00 binary"
OTHER_READERS = {
    "training config not UTF-8": ({"bad.toml": NOT_UTF8},
                                  ["pretrain", "good.npz", "-o", "r.pt", "--config", "bad.toml"]),
    "training config not TOML": ({"bad.toml": b"a = = 1"},
                                 ["pretrain", "good.npz", "-o", "r.pt", "--config", "bad.toml"]),
    "scene not UTF-8": ({"bad.toml": NOT_UTF8}, ["simulate", "bad.toml", "-o", "x.npz"]),
    "scene not TOML": ({"bad.toml": b"[motion\n"}, ["simulate", "bad.toml", "-o", "x.npz"]),
    "phantom set not UTF-8": ({"bad.toml": NOT_UTF8}, ["phantom", "--set", "bad.toml", "-o", "ph"]),
    "phantom set JSON not UTF-8": ({"bad.json": NOT_UTF8}, ["phantom", "--set", "bad.json", "-o", "ph"]),
    "camera not UTF-8": ({"bad.json": NOT_UTF8},
                         ["pose", "track", ".", "--camera", "bad.json", "-o", "p.jsonl"]),
    "camera a list": ({"bad.json": b"[1]"}, ["pose", "track", ".", "--camera", "bad.json", "-o", "p.jsonl"]),
    "pose rows not UTF-8": ({"bad.jsonl": NOT_UTF8}, ["pose", "accuracy", "bad.jsonl", "good.npz"]),
    "mri scan .npy garbage": ({"bad.npy": NOT_UTF8},
                              ["mri-label", "bad.npy", "--spacing-mm", "1,1,1", "-o", "l.nii.gz"]),
    "mri scan .npz garbage": ({"bad.npz": NOT_UTF8},
                              ["mri-label", "bad.npz", "--spacing-mm", "1,1,1", "-o", "l.nii.gz"]),
    "imager checkpoint garbage": ({"bad.pt": NOT_UTF8}, ["stream", "bad.pt", "good.npz"]),
}


@pytest.mark.parametrize("case", sorted(OTHER_READERS))
def test_bad_secondary_input(capsys, in_tmp, case):
    files, args = OTHER_READERS[case]
    save_scans("good.npz", random_scanset())
    for name, data in files.items():
        (in_tmp / name).write_bytes(data)
    line = fails_clearly(capsys, in_tmp, args, next(iter(files)))
    assert "allow_pickle" not in line


@pytest.mark.parametrize("make, words", [
    (lambda p: p.write_bytes(NOT_UTF8), "not a label .npy: not a .npy array"),
    (lambda p: np.save(p, np.zeros((26, 64, 64), np.uint8)),
     "label is 26 x 64 x 64, but the published layout"),
    (lambda p: np.save(p, np.array([{"a": 1}], dtype=object), allow_pickle=True), "refusing to unpickle"),
], ids=["garbage", "resampled", "pickled"])
def test_import_label_files(tmp_path, make, words):
    from lesscli.data.published import ImportOptions, find_label
    from lesscli.data.sources import FolderSource

    (tmp_path / "mri_images_3D").mkdir()
    make(tmp_path / "mri_images_3D" / "st12c13_0.npy")
    with pytest.raises(DataError, match=words) as err:
        find_label(FolderSource(str(tmp_path)), "St12C13", 0, ImportOptions())
    assert "st12c13_0.npy" in str(err.value)


def test_import_calibration_with_nan(tmp_path):
    from lesscli.data.published import load_calibration
    from lesscli.data.sources import FolderSource

    np.savez(tmp_path / "cal.npz", r_pos=np.eye(3), t_pos=np.array([0.0, np.nan, 0.0]), R_ori=np.eye(3))
    with pytest.raises(DataError, match=r"cal.npz: 't_pos' has NaN or inf"):
        load_calibration(FolderSource(str(tmp_path)), "cal.npz")

def test_pose_track_with_no_readable_frame_fails(capsys, in_tmp):
    (in_tmp / "frames").mkdir()
    for i in range(3):
        (in_tmp / "frames" / f"f{i}.png").write_bytes(b"not a png")
    (in_tmp / "c.json").write_text(json.dumps({"fx": 900, "fy": 900, "cx": 320, "cy": 240, "width": 640,
                                               "height": 480, "dist": [0, 0, 0, 0, 0]}))
    line = fails_clearly(capsys, in_tmp, ["pose", "track", "frames", "--camera", "c.json", "--fps", "30",
                                          "-o", "p.jsonl"], "frames")
    assert "none of the 3 frames could be read" in line


CAMERA = {"fx": 900, "fy": 900, "cx": 320, "cy": 240, "width": 640, "height": 480, "dist": [0, 0, 0, 0, 0]}
TIMESTAMP_CASES = {"a NaN time": "0.0\nnan\n0.2\n", "an infinite time": "0.0\n0.1\ninf\n",
                   "a NaN time by name": "f0.png 0.0\nf1.png NaN\nf2.png 0.2\n",
                   "times going back": "0.0\n0.2\n0.1\n", "a repeated time": "0.0\n0.1\n0.1\n"}


@pytest.mark.parametrize("case", sorted(TIMESTAMP_CASES))
def test_pose_track_refuses_timestamps_that_are_not_rising_finite_seconds(capsys, in_tmp, case):
    (in_tmp / "frames").mkdir()
    for i in range(3):
        (in_tmp / "frames" / f"f{i}.png").write_bytes(b"not a png")
    (in_tmp / "frames" / "timestamps.txt").write_text(TIMESTAMP_CASES[case])
    (in_tmp / "c.json").write_text(json.dumps(CAMERA))
    fails_clearly(capsys, in_tmp, ["pose", "track", "frames", "--camera", "c.json", "-o", "p.jsonl"],
                  "timestamps.txt")


@pytest.mark.parametrize("rate", ["nan", "inf", "0", "-30"])
def test_pose_track_refuses_a_frame_rate_that_is_not_a_positive_number(capsys, in_tmp, rate):
    (in_tmp / "frames").mkdir()
    (in_tmp / "c.json").write_text(json.dumps(CAMERA))
    with pytest.raises(SystemExit) as exc:
        main(["pose", "track", "frames", "--camera", "c.json", "-o", "p.jsonl", "--fps", rate])
    assert exc.value.code == 2 and "'--fps'" in capsys.readouterr().err and not (in_tmp / "p.jsonl").exists()


def test_resume_on_other_data_is_refused(capsys, in_tmp):
    save_scans("a.npz", random_scanset(seed=1))
    save_scans("b.npz", random_scanset(seed=2))
    with _no_exit():
        main(["-q", "pretrain", "a.npz", "-o", "rep.pt", "--epochs", "1", "--dim", "8", "--format", "jsonl"])
    capsys.readouterr()
    line = fails_clearly(capsys, in_tmp, ["pretrain", "b.npz", "-o", "rep.pt", "--epochs", "2", "--dim", "8",
                                          "--resume"], "rep.last.pt")
    assert "a.npz" in line and "b.npz" in line


# ---------------------------------------------------------------------------------------------- file modes

@pytest.mark.parametrize("umask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o027, 0o640, 0o750)])
def test_outputs_get_the_mode_of_a_plain_open(tmp_path, umask, file_mode, dir_mode):
    from lesscli.io.atomic import atomic_dir

    old = os.umask(umask)
    try:
        save_scans(str(tmp_path / "s.npz"), random_scanset())
        with atomic_dir(str(tmp_path / "out")) as tmp, open(os.path.join(tmp, "f.txt"), "w") as fh:
            fh.write("x")
    finally:
        os.umask(old)
    assert (tmp_path / "s.npz").stat().st_mode & 0o777 == file_mode
    assert (tmp_path / "out").stat().st_mode & 0o777 == dir_mode
    assert (tmp_path / "out" / "f.txt").stat().st_mode & 0o777 == file_mode


# ---------------------------------------------------------------------------------------------- zero-sample
# rule

def _run_ok(capsys, args) -> tuple[str, str]:
    with _no_exit():
        main([str(a) for a in args])
    return capsys.readouterr()


def test_a_scan_without_touches_images_as_nothing_known(capsys, in_tmp):
    """simulate -> (one scan left untouched) -> pretrain -> fit -> predict -> metrics, guide, noise-sweep."""
    from factories import TINY_SCENE

    from lesscli.io.predictions import load_predictions
    from lesscli.io.scans import load_scans

    (in_tmp / "tiny.toml").write_text(TINY_SCENE)
    _run_ok(capsys, ["-q", "simulate", "tiny.toml", "-o", "raw.npz"])
    raw = load_scans("raw.npz")
    save_scans("scans.npz", raw.select_trajectories(raw.traj_scan != 0))
    _, err = _run_ok(capsys, ["pretrain", "scans.npz", "-o", "rep.pt", "--epochs", "1", "--dim", "8",
                              "--format", "jsonl"])
    assert f"1 of {raw.n_scans} scans have no steps (untouched); training leaves them out" in err
    _run_ok(capsys, ["-q", "image", "fit", "scans.npz", "--rep", "rep.pt", "-o", "im.pt", "--epochs", "1",
                     "--format", "jsonl"])
    _run_ok(capsys, ["-q", "image", "predict", "im.pt", "scans.npz", "-o", "pred.npz", "--format", "jsonl"])
    preds = load_predictions("pred.npz").scans
    assert [p.steps == 0 for p in preds] == [True] + [False] * (raw.n_scans - 1)
    np.testing.assert_allclose(preds[0].probs.astype(np.float32), 0.25, atol=1e-3)
    np.testing.assert_allclose(preds[0].entropy.astype(np.float32), np.log(4), atol=1e-3)
    # touched: informed
    assert all(np.abs(p.probs.astype(np.float32) - 0.25).max() > 0.01 for p in preds[1:])
    rows = [json.loads(line)
            for line in _run_ok(capsys, ["metrics", "pred.npz", "--format", "jsonl"])[0].splitlines()]
    scan_rows = [r for r in rows if r["row"] == "scan"]
    assert len(scan_rows) == raw.n_scans and scan_rows[0]["steps"] == 0
    guided = json.loads(_run_ok(capsys, ["guide", "im.pt", "scans.npz", "--scan", "0", "--k", "1"])[0])
    assert guided["steps"] == 0 and abs(guided["mean_entropy_nats"] - np.log(4)) < 1e-4
    swept = _run_ok(capsys, ["noise-sweep", "im.pt", "scans.npz", "--pos-mm", "0,1", "--ang-rad", "0"])[0]
    assert len(swept.splitlines()) == 2
    empty = raw.select_trajectories(np.zeros(raw.n_traj, bool))
    save_scans("none.npz", empty)
    fails_clearly(capsys, in_tmp, ["pretrain", "none.npz", "-o", "r2.pt", "--epochs", "1"], "none.npz")
