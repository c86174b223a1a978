"""``less simulate`` through the console script, and its output through the dataset commands."""

import json

import numpy as np
from factories import TINY_SCENE

from lesscli.io.scans import load_scans


def test_simulate_then_info_subsample_concat_split(run_less, tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    sim = run_less("simulate", "tiny.toml", "-o", "raw.npz", "--jobs", "2", check=True)
    raw = load_scans(str(tmp_path / "raw.npz"))
    assert raw.n_scans == 4 and raw.n_traj == 12 and len(raw.labels) == 4
    (record,) = [json.loads(line) for line in sim.stdout.decode().splitlines()]
    assert (record["output"], record["scans"], record["trajectories"], record["steps"], record["seed"]) == \
        ("raw.npz", 4, 12, raw.n_steps, 3) and record["seconds"] >= 0
    assert list(raw.scan_insert) == ["St16C9", "St16C9", "St12D13", "St12D13"]
    assert raw.meta["simulation"]["tier"] == "winkler" and raw.meta["history"][-1]["seed"] == 3
    info = json.loads(run_less("info", "raw.npz", "--format", "jsonl", check=True).stdout)
    assert info["scans"] == 4
    run_less("subsample", "raw.npz", "--every", "50", "-o", "sub.npz", check=True)
    assert load_scans(str(tmp_path / "sub.npz")).traj_lengths().max() <= 10
    for i in range(2):
        run_less("simulate", "tiny.toml", "-o", f"shard{i}.npz", "--shard", f"{i}/2", check=True)
    run_less("concat", "shard0.npz", "shard1.npz", "-o", "joined.npz", check=True)
    joined = load_scans(str(tmp_path / "joined.npz"))
    assert np.array_equal(joined.force, raw.force) and np.array_equal(joined.pose, raw.pose)
    split = run_less("split", "raw.npz", "--by", "insert", "--test", "0.5", "-o", "split", "--format",
                     "jsonl", check=True)
    rows = [json.loads(line) for line in split.stdout.decode().splitlines()]
    assert sum(r["scans"] for r in rows) == 4


def test_simulate_overrides_and_errors(run_less, tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    run_less("simulate", "tiny.toml", "-o", "one.npz", "--set", "phantoms.names=[\"St12D13\"]",
             "--set", "phantoms.orientations=[1]", "--seed", "9", check=True)
    one = load_scans(str(tmp_path / "one.npz"))
    assert list(one.scan_insert) == ["St12D13"] and list(one.scan_orientation) == [1]
    assert one.meta["simulation"]["seed"] == 9
    bad = run_less("simulate", "tiny.toml", "-o", "bad.npz", "--set", "motion.n_trajs=2")
    assert bad.returncode == 1 and b"tiny.toml: unknown key 'motion.n_trajs'; did you mean 'motion.n_traj'?" \
        in bad.stderr
    assert not (tmp_path / "bad.npz").exists()
    assert run_less("simulate", "tiny.toml", "-o", "x.npz", "--shard", "2/2").returncode == 2
    missing = run_less("simulate", "nope.toml", "-o", "x.npz")
    assert missing.returncode == 1 and b"nope.toml: no such scene file" in missing.stderr


def test_jobs_default_to_the_cores_at_most_one_a_scan_and_follow_the_load_only_when_asked(tmp_path,
                                                                                        monkeypatch):
    from click.testing import CliRunner

    from lesscli import threads
    from lesscli.cli.main import cli

    (tmp_path / "tiny.toml").write_text(TINY_SCENE)
    monkeypatch.setattr(threads, "usable_cores", lambda: 3)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    runs = {}
    for load, orientations, jobs in ((0.0, "[0]", []), (0.0, "[0, 4]", []), (2.2, "[0]", []),
                                     (2.2, "[0]", ["--jobs", "auto"]), (2.2, "[0, 4]", ["--jobs", "auto"])):
        monkeypatch.setattr(threads, "load_average", lambda load=load: load)
        res = CliRunner().invoke(cli, ["simulate", str(tmp_path / "tiny.toml"), "-o", str(tmp_path / "x.npz"),
                                       "--set", f"phantoms.orientations={orientations}", "--set",
                                       "motion.n_traj=1", "--format", "jsonl", *jobs])
        assert res.exit_code == 0, res.output
        record = json.loads(res.stdout.strip().splitlines()[-1])
        runs[load, orientations, bool(jobs)] = (record["scans"], record["jobs"], record["threads"])
    # three cores: a worker each, but never more workers than scans, whatever the load; --jobs auto: one
    # free core (load 2.2), one worker
    assert runs == {(0.0, "[0]", False): (2, 2, 1), (0.0, "[0, 4]", False): (4, 3, 1),
                    (2.2, "[0]", False): (2, 2, 1), (2.2, "[0]", True): (2, 1, 1),
                    (2.2, "[0, 4]", True): (4, 1, 1)}


def test_thread_limit_reaches_the_blas_that_scipy_loads_later():
    """The simulator's linear algebra runs on scipy's own BLAS, loaded after the command set its threads."""
    import os
    import subprocess
    import sys

    code = ("import sys\nfrom lesscli.threads import set_threads\nset_threads(1, torch_too=False)\n"
            "assert 'scipy.linalg' not in sys.modules\nimport scipy.linalg\n"
            "from threadpoolctl import threadpool_info\n"
            "print(json.dumps({i['filepath']: i['num_threads'] for i in threadpool_info()}))")
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", "import json\n" + code], env=env, capture_output=True,
                         check=True)
    pools = json.loads(out.stdout)
    assert any("scipy" in path for path in pools) and set(pools.values()) == {1}, pools
