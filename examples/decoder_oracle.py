"""Can GLOBAL's image decoder draw the training labels when it is told the answer? A ceiling for `global`.

The global decoder (``lesscli.models.global_decoder``) is fitted, with the imaging loss and the schedule of
an imaging fit (Adam, batch 4), to a code that already holds the answer in place of the encoder's state:

    scan    one-hot of the scan: a pure look-up, the most a state could hold about its own scan
    answer  the true inclusion's centroid (voxel index scaled to [-1, 1]) and cube-root volume, with their
            sines and cosines: the few numbers a state would have to hold

It prints the training loss and the 3D micro inclusion F1 (argmax) on the fitted scans every 10 epochs, and
with ``--val`` the F1 of the ``answer`` code on other scans. An imager cannot score above what its decoder
scores here on its own training scans, whatever its encoder learns.

    python examples/decoder_oracle.py work/accuracy-winkler/search/train.npz --width 32 --epochs 20
    python examples/decoder_oracle.py ... --code answer --val work/accuracy-winkler/split/val.npz
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lesscli.data.image_labels import training_targets
from lesscli.io.labels import INCLUSION
from lesscli.io.scans import load_scans
from lesscli.metrics.masks import confusion, f1_from
from lesscli.models.encoders import ParticleStates
from lesscli.models.global_decoder import GlobalDecoder
from lesscli.models.imaging_loss import imaging_loss


def labels(path: str):
    targets, grid = training_targets(load_scans(path), 3)
    return torch.from_numpy(np.stack(targets).astype(np.int64)), grid


def answer_code(y: torch.Tensor) -> torch.Tensor:
    """(n, 12): each scan's true inclusion centroid and cube-root volume, with their sines and cosines."""
    rows = []
    for t in y:
        idx = (t == INCLUSION).nonzero().float()
        if len(idx) == 0:
            rows.append([0.0] * 4)
            continue
        centre = idx.mean(0) / torch.tensor(t.shape, dtype=torch.float32) * 2 - 1
        rows.append([*centre.tolist(), len(idx) ** (1 / 3) / 10])
    p = torch.tensor(rows)
    return torch.cat([p, torch.sin(3 * p), torch.cos(3 * p)], 1)


def decode(decoder: GlobalDecoder, z: torch.Tensor, grid) -> torch.Tensor:
    seen = torch.ones(len(z), 1, dtype=torch.bool)
    states = ParticleStates(z=z[:, None], xy_mm=torch.zeros(1, 2), seen=seen)
    return decoder(states, grid)


def f1(decoder: GlobalDecoder, code: torch.Tensor, y: torch.Tensor, grid) -> float:
    """Micro inclusion F1 of the argmax over all scans (0 when no voxel is predicted or true)."""
    counts = np.zeros(3, dtype=np.int64)
    with torch.no_grad():
        for i in range(0, len(y), 8):
            pred = decode(decoder, code[i:i + 8], grid).argmax(1) == INCLUSION
            counts += confusion(pred.numpy(), (y[i:i + 8] == INCLUSION).numpy())
    return f1_from(*map(int, counts)) or 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("train")
    ap.add_argument("--val", help="scans to score the answer code on (not fitted)")
    ap.add_argument("--code", choices=("scan", "answer"), default="scan")
    ap.add_argument("--width", type=int, default=32, help="image.width of the decoder")
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--alpha-power", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.val and args.code == "scan":
        ap.error("--val needs --code answer (a one-hot of the training scans says nothing of others)")
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    y, grid = labels(args.train)
    code = torch.eye(len(y)) if args.code == "scan" else answer_code(y)
    val = labels(args.val) if args.val else None
    val_code = answer_code(val[0]) if val is not None else None
    decoder = GlobalDecoder(code.shape[1], 4, 3, grid.shape, args.width)
    opt = torch.optim.Adam(decoder.parameters(), lr=args.lr)
    t0 = time.perf_counter()
    for epoch in range(1, args.epochs + 1):
        total = 0.0
        for idx in torch.randperm(len(y)).split(4):
            loss = imaging_loss(decode(decoder, code[idx], grid), y[idx], alpha_power=args.alpha_power).total
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        if epoch % 10 == 0 or epoch == args.epochs:
            line = (f"code {args.code} width {args.width} epoch {epoch}: loss {total / len(y):.3f}, "
                    f"train F1 {f1(decoder, code, y, grid):.3f}")
            if val is not None:
                line += f", val F1 {f1(decoder, val_code, val[0], grid):.3f}"
            print(f"{line} ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
