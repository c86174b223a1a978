"""``less pose`` through the installed console script: render -> track -> accuracy, calibrate, apply,
errors."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from lesscli.geometry import rotations
from lesscli.io.scans import load_scans
from lesscli.vision.camera import default_camera, save_camera


def _rows(text: bytes) -> list[dict]:
    return [json.loads(line) for line in text.decode().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory):
    from conftest import BIN

    root = tmp_path_factory.mktemp("pose")
    proc = subprocess.run([str(BIN / "less"), "-q", "pose", "render", "--frames", "4", "--step", "25",
                           "--seed", "3", "-o", str(root / "frames")], capture_output=True, check=False)
    assert proc.returncode == 0, proc.stderr.decode()
    return root / "frames"


def test_pose_module_does_not_import_cv2_at_top():
    code = "import sys, lesscli.cli.pose; print('cv2' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_render_track_accuracy_pipeline(run_less, frames_dir, tmp_path):
    names = sorted(p.name for p in frames_dir.iterdir())
    assert {"camera.json", "timestamps.txt", "truth.npz", "trajectory.npz", "frame_00000.png"} <= set(names)
    poses = tmp_path / "poses.jsonl"
    run_less("pose", "track", frames_dir, "--camera", frames_dir / "camera.json", "-o", poses, check=True)
    rows = _rows(poses.read_bytes())
    assert [r["frame"] for r in rows] == [0, 1, 2, 3] and all(r["ok"] for r in rows)
    assert set(rows[0]) >= {"frame", "t", "position_mm", "rotvec_rad", "tags_seen", "reprojection_px", "ok"}
    assert rows[0]["tags_seen"] == [0, 1] and len(rows[0]["position_mm"]) == 3
    plot = tmp_path / "err.png"
    proc = run_less("pose", "accuracy", poses, frames_dir / "truth.npz", "--plot", plot, check=True)
    (summary,) = _rows(proc.stdout)
    assert summary["n_poses"] == 4
    assert summary["sigma_positional_mm"] < 1.0 and summary["sigma_angular_rad"] < 0.01
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_missing_tags_and_corrupt_image_give_ok_false_rows(run_less, frames_dir, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    (folder / "a.png").write_bytes((frames_dir / "frame_00000.png").read_bytes())
    cv2.imwrite(str(folder / "b.png"), np.full((720, 1280), 128, np.uint8))      # no tags
    (folder / "c.png").write_bytes(b"this is not a png")                          # corrupt
    proc = run_less("pose", "track", folder, "--camera", frames_dir / "camera.json", "--fps", "30", "-o", "-",
                    check=True)
    rows = _rows(proc.stdout)
    assert [r["ok"] for r in rows] == [True, False, False]
    assert rows[1]["position_mm"] == [None, None, None] and rows[1]["tags_seen"] == []
    assert "unreadable" in rows[2]["note"]
    assert "frame 2: unreadable image" in proc.stderr.decode()


def test_wrong_camera_file_is_one_line_error(run_less, frames_dir, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"fx": 900, "fy": 900}')
    out = tmp_path / "poses.jsonl"
    proc = run_less("pose", "track", frames_dir, "--camera", bad, "-o", out)
    err = proc.stderr.decode().strip()
    assert proc.returncode == 1 and len(err.splitlines()) == 1 and "lacks 'cx'" in err
    small = tmp_path / "small.json"
    save_camera(str(small), default_camera().__class__(500, 500, 319.5, 239.5, 640, 480))
    proc = run_less("pose", "track", frames_dir, "--camera", small, "-o", out)
    err = proc.stderr.decode().strip()
    assert proc.returncode == 1 and len(err.splitlines()) == 1 and "1280x720" in err and "640x480" in err
    assert not out.exists()
    (tmp_path / "junk.json").write_text("{not json")
    proc = run_less("pose", "track", frames_dir, "--camera", tmp_path / "junk.json", "-o", out)
    assert proc.returncode == 1 and "not valid JSON" in proc.stderr.decode()


def _write_streams(tmp_path, rng):
    t = np.arange(0, 20, 1 / 30)
    pos = np.stack([50 * np.sin(0.8 * t), 40 * np.sin(1.3 * t + 1), 20 * np.sin(0.5 * t)], axis=1)
    rv = np.stack([0.2 * np.sin(t), 0.1 * np.cos(0.7 * t), 0.3 * np.sin(0.3 * t)], axis=1)
    rot_true = rotations.rotvec_to_matrix(np.array([0.2, 0.9, -0.4]))
    t_true = np.array([300.0, 20.0, -150.0])
    est = tmp_path / "est.jsonl"
    noisy = pos + rng.normal(0, 0.5, pos.shape)
    est.write_text("".join(json.dumps({"frame": i, "t": float(t[i]), "position_mm": noisy[i].tolist(),
                                       "rotvec_rad": rv[i].tolist(), "ok": True}) + "\n"
                                       for i in range(len(t))))
    robot = tmp_path / "robot.npz"
    np.savez(robot, time_s=t, position_mm=pos @ rot_true.T + t_true,
             rotation=rot_true @ rotations.rotvec_to_matrix(rv))
    return est, robot, rot_true, t_true


def test_calibrate_accuracy_and_apply(run_less, scanset_file, tmp_path):
    est, robot, _, t_true = _write_streams(tmp_path, np.random.default_rng(0))
    cal = tmp_path / "cal.npz"
    proc = run_less("pose", "calibrate", est, robot, "-o", cal, "--max-offset-s", "0.2", check=True)
    (row,) = _rows(proc.stdout)
    assert abs(row["time_offset_s"]) < 0.01 and row["inlier_fraction"] > 0.95
    with np.load(cal) as npz:
        assert npz["r_pos"].shape == (3, 3) and npz["t_pos"].shape == (3,) and npz["R_ori"].shape == (3, 3)
        assert np.linalg.norm(npz["t_pos"] - t_true) < 0.5
    proc = run_less("pose", "accuracy", est, robot, "--calibration", cal, check=True)
    (acc,) = _rows(proc.stdout)
    assert 0.3 < acc["sigma_positional_mm"] < 0.7 and acc["sigma_angular_rad"] < 0.01
    out = tmp_path / "out.npz"
    run_less("pose", "apply", cal, scanset_file, "-o", out, check=True)
    before, after = load_scans(str(scanset_file)), load_scans(str(out))
    with np.load(cal) as npz:
        expected = before.pose[:, :3].astype(np.float64) @ npz["r_pos"].T + npz["t_pos"]
    assert np.allclose(after.pose[:, :3], expected, atol=1e-3)
    assert "pose apply" in after.meta["history"][-1]["command"]


def test_calibrate_degenerate_streams_fail_cleanly(run_less, tmp_path):
    t = np.arange(0, 5, 0.1)
    line = np.stack([t * 10, t * 5, -t], axis=1)
    est = tmp_path / "line.jsonl"
    est.write_text("".join(json.dumps({"t": float(t[i]), "position_mm": line[i].tolist(),
                                       "rotvec_rad": [0, 0, 0]}) + "\n" for i in range(len(t))))
    robot = tmp_path / "robot.npz"
    np.savez(robot, time_s=t, position_mm=line + 100, rotvec_rad=np.zeros((len(t), 3)))
    out = tmp_path / "cal.npz"
    proc = run_less("pose", "calibrate", est, robot, "-o", out, "--max-offset-s", "0")
    assert proc.returncode == 1 and "one line" in proc.stderr.decode() and not out.exists()
    np.savez(robot, time_s=t + 50, position_mm=line + 100, rotvec_rad=np.zeros((len(t), 3)))
    proc = run_less("pose", "calibrate", est, robot, "-o", out)
    assert proc.returncode == 1 and "no time overlap" in proc.stderr.decode()
