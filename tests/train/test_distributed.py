"""Two CPU processes with the gloo backend: both ranks finish, rank 0 alone writes."""

from __future__ import annotations

import json
import os
import socket

import torch
import torch.multiprocessing as mp
from factories import random_scanset

WORLD = 2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _worker(rank: int, port: int, folder: str) -> None:
    """One rank: the environment torchrun would set, then the library entry point."""
    torch.set_num_threads(1)
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "RANK": str(rank),
                       "WORLD_SIZE": str(WORLD), "LOCAL_RANK": str(rank)})
    from lesscli.train import distributed, loop
    from lesscli.train.config import PretrainConfig
    from lesscli.train.pretrain import pretrain

    real_save = loop.save_checkpoint

    def recording_save(path, *args, **kwargs):
        with open(os.path.join(folder, "writes.txt"), "a") as fh:
            fh.write(f"{rank} {os.path.basename(path)}\n")
        real_save(path, *args, **kwargs)

    loop.save_checkpoint = recording_save
    cfg = PretrainConfig()
    cfg.model.dim, cfg.model.n_freq, cfg.model.spacing_mm = 8, 2, 10.0
    cfg.train.epochs, cfg.train.device, cfg.ssl.k_input, cfg.ssl.k_query = 2, "cpu", 4, 4
    env = distributed.setup("cpu")
    try:
        summary = pretrain(random_scanset(n_scans=4, seed=1), random_scanset(n_scans=2, seed=2), cfg,
                           os.path.join(folder, "rep.pt"), env=env)
    finally:
        distributed.teardown(env)
    with open(os.path.join(folder, f"done{rank}.json"), "w") as fh:
        json.dump({"rank": env.rank, "world": env.world_size, "best_loss": summary["best_loss"]}, fh)


def test_two_gloo_ranks_finish_and_only_rank0_writes(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    mp.spawn(_worker, args=(_free_port(), str(out)), nprocs=WORLD, join=True)
    done = [json.loads((out / f"done{r}.json").read_text()) for r in range(WORLD)]
    assert [d["rank"] for d in done] == [0, 1] and all(d["world"] == WORLD for d in done)
    writers = {line.split()[0] for line in (out / "writes.txt").read_text().splitlines()}
    assert writers == {"0"}
    ckpt = torch.load(str(out / "rep.pt"), weights_only=True)
    epochs = [h for h in ckpt["history"] if "epoch" in h]
    # 4 scans, batch 2, split over 2 ranks by the distributed sampler: one step per epoch and rank
    assert [h["step"] for h in epochs] == [1, 2]
    assert len((out / "rep.log.jsonl").read_text().splitlines()) == 2
    assert sorted(p.name for p in out.iterdir() if p.suffix in (".pt", ".jsonl")) == \
        ["rep.last.pt", "rep.log.jsonl", "rep.pt"]
