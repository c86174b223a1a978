"""GLOBAL's decoder told the answer (examples/decoder_oracle.py): the codes and the F1 it reports."""

from __future__ import annotations

import torch
from factories import example_script

from lesscli.io.labels import INCLUSION


def test_the_answer_code_holds_the_centroid_and_size_and_is_zero_without_an_inclusion():
    oracle = example_script("decoder_oracle")
    y = torch.zeros(2, 4, 8, 8, dtype=torch.int64)
    y[0, 1:3, 2:4, 4:8] = INCLUSION                        # 16 voxels centred at (1.5, 2.5, 5.5)
    code = oracle.answer_code(y)
    assert code.shape == (2, 12)
    centre = torch.tensor([1.5 / 4, 2.5 / 8, 5.5 / 8]) * 2 - 1
    assert torch.allclose(code[0, :3], centre)
    assert torch.isclose(code[0, 3], torch.tensor(16 ** (1 / 3) / 10))
    assert torch.allclose(code[0, 4:8], torch.sin(3 * code[0, :4]))
    assert torch.equal(code[1, :4], torch.zeros(4))


class _Echo(torch.nn.Module):
    """Logits that put the inclusion wherever the code's first number is positive."""

    def forward(self, states, grid):
        on = (states.z[:, 0, 0] > 0).float()[:, None, None, None]
        logits = torch.zeros(len(on), 4, *grid.shape)
        logits[:, INCLUSION] = on * 2 - 1
        return logits


def test_f1_is_micro_over_the_scans_voxels():
    oracle = example_script("decoder_oracle")
    grid = type("Grid", (), {"shape": (1, 2, 2)})()
    y = torch.zeros(3, 1, 2, 2, dtype=torch.int64)
    y[0, 0, 0] = INCLUSION                                 # 2 true voxels in scan 0, 4 in scan 1, none in 2
    y[1] = INCLUSION
    code = torch.tensor([[1.0], [-1.0], [1.0]])            # predicts all of scans 0 and 2, none of 1
    # tp 2, fp 2 (scan 0) + 4 (scan 2), fn 4 (scan 1): 2 * 2 / (4 + 6 + 4)
    assert abs(oracle.f1(_Echo(), code, y, grid) - 4 / 14) < 1e-9
