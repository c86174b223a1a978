"""Force decoder: predict the force at a (centred) query pose from a particle state.

``FD(z, pose) = MLP_out(PE(pose) + MLP_z(z))``; the state and query halves are computed once and
broadcast, so K states x K' queries cost K + K' encodings. The first layer of ``MLP_out`` is linear, so it
is applied to each half before the broadcast (``W (a + b) = W a + W b``): only the activation and the
last layer, d_z -> F, run over the K x K' pairs.
"""

from __future__ import annotations

from torch import Tensor, nn

from lesscli.models.encoding import PoseEncoding
from lesscli.models.layers import mlp


class ForceDecoder(nn.Module):
    """Decode forces from particle states at query poses.

    Args:
        force_dim: F, force features to predict.
        dim: d_z (state width, also the hidden width).
        n_freq: wavelengths per pose coordinate.
    """

    name = "mlp"

    def __init__(self, force_dim: int, dim: int, n_freq: int = 16) -> None:
        super().__init__()
        self.settings = {"force_dim": int(force_dim), "dim": int(dim), "n_freq": int(n_freq)}
        self.pose_encoding = PoseEncoding(dim, n_freq)
        self.state_mlp = mlp(dim, dim, dim)
        self.out_mlp = mlp(dim, dim, force_dim)

    def forward(self, z: Tensor, pose: Tensor) -> Tensor:
        """All pairs of states and queries.

        Args:
            z: (N, K, d_z) states.
            pose: (N, K', 6) query poses, x-y centred on the particle (mm, rad).

        Returns:
            (N, K, K', F) predicted (normalised) forces.
        """
        first, act, last = self.out_mlp
        states = first(self.state_mlp(z))                                        # (N, K, d_z), with the bias
        queries = self.pose_encoding(pose) @ first.weight.t()                   # (N, K', d_z)
        return last(act(states[:, :, None, :] + queries[:, None, :, :]))
