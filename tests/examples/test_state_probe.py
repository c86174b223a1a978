"""What one GLOBAL state holds (examples/state_probe.py): its memory horizon and the linear probe."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from factories import REPO, example_script

from lesscli.models.encoders import GlobalEncoder
from lesscli.types import Batch


@pytest.fixture
def probe_script(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "examples"))        # it reads decoder_oracle beside it
    return example_script("state_probe")


def _scan(steps: int = 30) -> Batch:
    g = torch.Generator().manual_seed(3)
    pose = torch.randn(1, steps, 6, generator=g) * torch.tensor([10.0, 10, 2, 0.01, 0.01, 0.5])
    return Batch(pose=pose, force=torch.randn(1, steps, 6, generator=g),
                 valid=torch.ones(1, steps, dtype=torch.bool), scan_index=torch.zeros(1, dtype=torch.long))


def test_a_state_without_recurrence_remembers_only_its_last_step(probe_script):
    torch.manual_seed(0)
    encoder = GlobalEncoder(6, dim=8)
    norms = probe_script.horizon(encoder, _scan())
    assert norms.shape == (30,) and norms[0] > 0 and (norms[1:] > 0).all()   # a GRU carries the past
    with torch.no_grad():
        encoder.gru.weight_hh_l0.zero_()                       # gates and candidate read the input alone
        h = encoder.dim
        encoder.gru.bias_hh_l0[h:2 * h].fill_(-30.0)           # update gate shut: nothing is kept
    norms = probe_script.horizon(encoder, _scan())
    assert norms[0] > 0 and np.abs(norms[1:]).max() < 1e-9


def test_the_probe_finds_what_the_states_hold_and_nothing_in_noise(probe_script):
    rng = np.random.default_rng(0)
    y_train, y_val = rng.normal(size=(200, 4)), rng.normal(size=(50, 4))
    mix = rng.normal(size=(4, 16))
    held = probe_script.probe(y_train @ mix, y_train, y_val @ mix, y_val, ridge=1e-6)
    assert all(np.allclose(r2, 1.0, atol=1e-6) for r2 in held)
    train_r2, val_r2 = probe_script.probe(rng.normal(size=(200, 16)), y_train, rng.normal(size=(50, 16)),
                                          y_val)
    assert (train_r2 < 0.2).all() and (val_r2 < 0.1).all()    # about d / n = 0.08 where it was fitted
