"""What one GLOBAL state holds: how far back in a scan it remembers, and whether it holds the inclusion.

For a single-state representation (`global`, from `less pretrain`) and scans with labels it prints

    horizon  the sensitivity of the state at a scan's last step to the encoder input of a step ``lag`` steps
             before it (Frobenius norm of the Jacobian, mean over the first scans), relative to lag 0: a
             state that forgets all but its last pokes cannot hold an inclusion touched earlier
    probe    a ridge regression from the final states to the true inclusion's centroid (voxel index scaled
             to [-1, 1]) and cube-root volume, fitted on the training scans and scored (R^2) on them and on
             the validation scans; with d_z features and n scans, a state that holds nothing scores about
             d_z / n on its training scans and <= 0 on the others

    python examples/state_probe.py work/accuracy-winkler/paper/rep_global_s0.pt \\
        work/accuracy-winkler/paper/train.npz work/accuracy-winkler/paper/val.npz
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from decoder_oracle import answer_code, labels

from lesscli.data.batching import batches
from lesscli.io.scans import load_scans
from lesscli.train.representation import load_representation

LAGS = (0, 5, 10, 20, 40, 80, 120, 160)
TARGETS = ("depth", "row", "column", "size")


def horizon(encoder, batch) -> np.ndarray:
    """(T,) Jacobian norm of the last state with respect to the input of each step, last step first."""
    seq = encoder.gather_sequence(batch)
    inputs = []

    def track(module, args, out):                       # the encoder's own path, from a leaf input on
        inputs.append(out.detach().requires_grad_(True))
        return inputs[-1]

    hook = encoder.fle.register_forward_hook(track)
    try:
        z = encoder.states_at(batch, seq)
    finally:
        hook.remove()
    x, last = inputs[0], z[0, seq.count[0] - 1]
    jac = torch.stack([torch.autograd.grad(last[k], x, retain_graph=True)[0] for k in range(last.shape[0])])
    return jac.norm(dim=(0, 2)).numpy()[::-1]


def final_states(encoder, scans, stats) -> np.ndarray:
    with torch.no_grad():
        return torch.cat([encoder(b).z[:, 0] for b in batches(scans, stats, 8)]).numpy()


def probe(z_train: np.ndarray, y_train: np.ndarray, z_val: np.ndarray, y_val: np.ndarray,
          ridge: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """R^2 per target of a ridge regression from states to targets, on the scans it was fitted on and on
    others (both against the training targets' mean)."""
    mu, sd = z_train.mean(0), z_train.std(0) + 1e-8
    x_train = np.c_[(z_train - mu) / sd, np.ones(len(z_train))]
    x_val = np.c_[(z_val - mu) / sd, np.ones(len(z_val))]
    penalty = ridge * np.eye(x_train.shape[1])
    penalty[-1, -1] = 0.0                                           # the intercept is not shrunk
    w = np.linalg.solve(x_train.T @ x_train + penalty, x_train.T @ y_train)

    def r2(x, y):
        return 1 - ((x @ w - y) ** 2).sum(0) / ((y - y_train.mean(0)) ** 2).sum(0)

    return r2(x_train, y_train), r2(x_val, y_val)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rep")
    ap.add_argument("train")
    ap.add_argument("val")
    ap.add_argument("--scans", type=int, default=12, help="scans the horizon is averaged over")
    ap.add_argument("--ridge", type=float, default=1.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    encoder, ckpt = load_representation(args.rep)
    if encoder.n_particles != 1:
        raise SystemExit(f"{args.rep}: {encoder.n_particles} particles; the probe reads one state per scan")
    stats = ckpt["norm_stats"]
    train, val = load_scans(args.train), load_scans(args.val)
    norms = [horizon(encoder, b) for b in batches(train, stats, 1)[:args.scans]]
    mean = np.mean([n[:min(map(len, norms))] for n in norms], axis=0)
    print(f"{args.rep}: d_z {encoder.dim}, {train.n_scans} training scans, {val.n_scans} validation scans")
    print("horizon (last state's sensitivity to a step `lag` steps before the last, relative to lag 0): "
          + ", ".join(f"lag {lag} {mean[lag] / mean[0]:.2g}" for lag in LAGS if lag < len(mean)))
    z_train, z_val = final_states(encoder, train, stats), final_states(encoder, val, stats)
    y_train = answer_code(labels(args.train)[0])[:, :4].numpy()
    y_val = answer_code(labels(args.val)[0])[:, :4].numpy()
    for name, score in zip(("training", "validation"), probe(z_train, y_train, z_val, y_val, args.ridge)):
        print(f"probe R^2 on the {name} scans: " + ", ".join(f"{t} {v:.2f}" for t, v in zip(TARGETS, score)))
    print(f"(a state that holds nothing: about {encoder.dim / train.n_scans:.2f} on the training scans, "
          "<= 0 on the validation scans)")


if __name__ == "__main__":
    main()
