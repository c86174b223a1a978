"""A checkpoint and a scan set that differ in force units, pose units or taxel layout: every command that
combines them exits 1 with one line naming both files and writes nothing; implausible scans are refused."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from imaging_factory import learnable_scanset, make_representation, tiny_imager

from lesscli.data.compat import signature
from lesscli.io.checkpoint import save_checkpoint
from lesscli.io.scans import save_scans


def _variant(scans, kind: str):
    out = copy.deepcopy(scans)
    if kind == "counts":
        out.meta["units"]["force"] = "counts"
        out.force = out.force * 1000
    elif kind == "metres":
        out.meta["units"]["pose"] = ["m", "m", "m", "rad", "rad", "rad"]
    elif kind == "layout":
        out.meta["sensor"] = {**out.meta["sensor"],
                              "taxel_xy_mm": (np.asarray(out.meta["sensor"]["taxel_xy_mm"]) * 0.75).tolist()}
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("units")
    scans = learnable_scanset(3, seed=5, steps_per_traj=6, traj_per_scan=8)
    save_scans(str(folder / "ok.npz"), scans)
    for kind in ("counts", "metres", "layout"):
        save_scans(str(folder / f"{kind}.npz"), _variant(scans, kind))
    make_representation(str(folder / "rep.pt"), scans, dim=8)
    imager, stats, config = tiny_imager(dim=2)
    save_checkpoint(str(folder / "im.pt"), imager.state_dict(), config, {**stats, "data": signature(scans)},
                    [])
    return folder


KINDS = {"counts": "force units 'counts' vs 'N'", "metres": "pose units 'm,m,m,rad,rad,rad' vs",
         "layout": "taxel layout differs"}


def _refused(proc, scans: str, model: str, what: str, folder, out: str | None = None) -> None:
    err = proc.stderr.decode()
    assert proc.returncode == 1, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and scans in lines[0] and model in lines[0] and what in lines[0], err
    if out:
        assert not (folder / out).exists()


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_image_predict_refuses_a_mismatched_scan_set(files, run_less, kind):
    proc = run_less("image", "predict", "im.pt", f"{kind}.npz", "-o", "p.npz", cwd=files)
    _refused(proc, f"{kind}.npz", "im.pt", KINDS[kind], files, "p.npz")


def test_image_fit_refuses_scans_that_do_not_match_the_representation(files, run_less):
    proc = run_less("image", "fit", "counts.npz", "--rep", "rep.pt", "-o", "fit.pt", "--epochs", "1",
                    cwd=files)
    _refused(proc, "counts.npz", "rep.pt", KINDS["counts"], files, "fit.pt")


def test_pretrain_refuses_a_validation_set_that_does_not_match_the_training_set(files, run_less):
    proc = run_less("pretrain", "ok.npz", "--val", "layout.npz", "-o", "rep2.pt", "--epochs", "1", "--dim",
                    "8", cwd=files)
    _refused(proc, "layout.npz", "ok.npz", KINDS["layout"], files, "rep2.pt")


def test_stream_guide_and_noise_sweep_refuse_a_mismatched_scan_set(files, run_less):
    _refused(run_less("stream", "im.pt", "counts.npz", cwd=files), "counts.npz", "im.pt", KINDS["counts"],
             files)
    _refused(run_less("guide", "im.pt", "counts.npz", cwd=files), "counts.npz", "im.pt", KINDS["counts"],
             files)
    proc = run_less("noise-sweep", "im.pt", "metres.npz", "--pos-mm", "0", "--ang-rad", "0", "--plot",
                    "n.png", cwd=files)
    _refused(proc, "metres.npz", "im.pt", KINDS["metres"], files, "n.png")


def test_the_force_map_refuses_a_mismatched_scan_set(files, run_less):
    run_less("image", "fit", "ok.npz", "--model", "forcemap", "-o", "fm.pt", cwd=files, check=True)
    proc = run_less("image", "predict", "fm.pt", "counts.npz", "-o", "q.npz", cwd=files)
    _refused(proc, "counts.npz", "fm.pt", KINDS["counts"], files, "q.npz")


def test_implausible_poses_and_forces_are_refused_naming_the_file(files, run_less, tmp_path):
    from lesscli.io.scans import load_scans

    scans = load_scans(str(files / "ok.npz"))
    far = copy.deepcopy(scans)
    far.pose[:, :3] *= 1e4                                  # micrometres read as mm
    huge = copy.deepcopy(scans)
    huge.force[..., 2] += 1e30
    degrees = copy.deepcopy(scans)
    degrees.pose[:, 5] = 45.0
    for name, bad, what in (("far.npz", far, "from the phantom's centre"),
                            ("huge.npz", huge, "sensor counts"), ("deg.npz", degrees, "in degrees")):
        save_scans(str(tmp_path / name), bad)
        proc = run_less("image", "predict", files / "im.pt", name, "-o", "p.npz", cwd=tmp_path)
        _refused(proc, name, name, what, tmp_path, "p.npz")


def test_live_stream_puts_each_pose_on_the_surface_of_the_touches_so_far(files, run_less, tmp_path):
    """A model in the surface frame images live samples as a StreamingImager fed the OnlineSurface's poses;
    the same samples in the pose frame image differently (the top sits 2 mm up)."""
    import json

    import torch

    from lesscli.data.surface import FRAME, OnlineSurface
    from lesscli.infer.stream import StreamingImager, entropy_summary
    from lesscli.io.scans import load_scans

    scans = load_scans(str(files / "ok.npz"))
    imager, stats, config = tiny_imager(dim=2)
    sig = {**signature(scans), "pose_frame": FRAME}
    save_checkpoint(str(tmp_path / "sf.pt"), imager.state_dict(), config, {**stats, "data": sig}, [])
    pose = scans.pose.astype(np.float64)
    pose[:, 2] += 2.0
    times = np.arange(scans.n_steps) * 0.5                  # live time never goes back
    lines = [json.dumps({"t": float(t), "pose": p.tolist(), "force": f.tolist()})
             for t, p, f in zip(times, pose, scans.force.astype(np.float64))]
    proc = run_less("stream", tmp_path / "sf.pt", "-", "--emit-every", str(scans.n_steps),
                    input="\n".join(lines).encode(), check=True)
    (row,) = [json.loads(line) for line in proc.stdout.decode().splitlines() if line.strip()]

    def final_entropy(on_surface: bool) -> float:
        stream = StreamingImager(imager, stats)
        online = OnlineSurface(scans.meta["sensor"], scans.n_taxels)
        with torch.no_grad():
            for t, p, f in zip(times, pose, scans.force):
                stream.push(online.push(p, f, float(t)) if on_surface else p, f)
        return entropy_summary(stream.entropy(), stream.probs().shape[0])["entropy_mean_nats"]

    assert row["entropy_mean_nats"] == pytest.approx(final_entropy(True), abs=1e-4)
    assert abs(final_entropy(False) - final_entropy(True)) > 1e-3
