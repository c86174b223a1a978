"""LESS particle encoder and the GLOBAL single-state baseline.

For every particle: gather its in-field steps in time order, centre their x-y on the particle,
encode each (pose, force) pair with the force-location encoder (sinusoidal pose encoding + MLP of
the force, summed), and run one GRU whose weights all particles share. Only particles that saw at
least one step are run, each only over its own real steps (:mod:`lesscli.models.recurrence`): the
state read at the last real step equals a masked update, and no compute is spent on padding or on
particles that saw nothing. Training and evaluation take the same path.

A particle's state is a function of its own gathered steps only: touches added or moved outside its
receptive field leave it unchanged to float rounding (~1e-7: the matrix sizes follow the other
particles' step counts, and BLAS may round a row differently in a product of another size).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lesscli.models.encoding import POSE_DIM, PoseEncoding
from lesscli.models.force_decoder import ForceDecoder
from lesscli.models.layers import mlp
from lesscli.models.particles import Gathered, gather_receptive_field, particle_grid
from lesscli.models.recurrence import ragged_gru
from lesscli.types import Batch


@dataclass
class ParticleStates:
    """Final particle states.

    Attributes:
        z: (B, P, d_z) float, the state at each particle's last valid step (zeros when it saw nothing).
        xy_mm: (P, 2) particle positions in the phantom frame (GLOBAL: P = 1, xy = 0).
        seen: (B, P) bool, the particle saw at least one step.
    """

    z: Tensor
    xy_mm: Tensor
    seen: Tensor


@dataclass
class SeenRows:
    """The receptive-field gather and its N seen (batch, particle) rows.

    Attributes:
        gathered: the gather over the whole (B, P) grid.
        batch_index, particle_index: (N,) long, which (b, p) each row is.
        step_index: (N, C) long, the step of each slot (see :class:`Gathered`).
        pose: (N, C, 6) gathered poses, x-y centred on the particle.
        mask: (N, C) bool, real steps.
    """

    gathered: Gathered
    batch_index: Tensor
    particle_index: Tensor
    step_index: Tensor
    pose: Tensor
    mask: Tensor

    @property
    def count(self) -> Tensor:
        """(N,) long, real steps per row."""
        return self.gathered.count[self.batch_index, self.particle_index]


@dataclass
class ParticleSequence:
    """GRU outputs for the particles that saw something (N rows = seen (batch, particle) pairs).

    Attributes:
        batch_index, particle_index: (N,) long, which (b, p) each row is.
        z: (N, C, d_z) GRU state after each gathered step (None from ``gather_sequence``).
        pose: (N, C, 6) gathered poses, x-y centred on the particle.
        force: (N, C, F) gathered forces (normalised).
        mask: (N, C) bool, real steps (pose/force slots past ``count`` repeat the last step; z is 0 there).
        count: (N,) long, real steps per row (>= 1).
        shape: (B, P) of the full particle grid.
        xy_mm: (P, 2) particle positions.
    """

    batch_index: Tensor
    particle_index: Tensor
    z: Tensor | None
    pose: Tensor
    force: Tensor
    mask: Tensor
    count: Tensor
    shape: tuple[int, int]
    xy_mm: Tensor

    def final_states(self) -> ParticleStates:
        """Scatter each row's state at its last real step into a (B, P, d_z) tensor."""
        b, p = self.shape
        rows = torch.arange(self.z.shape[0], device=self.z.device)
        last = self.z[rows, self.count - 1]
        z = self.z.new_zeros(b, p, self.z.shape[-1])
        z = z.index_put((self.batch_index, self.particle_index), last)
        seen = torch.zeros(b, p, dtype=torch.bool, device=self.z.device)
        seen[self.batch_index, self.particle_index] = True
        return ParticleStates(z=z, xy_mm=self.xy_mm, seen=seen)


class ForceLocationEncoder(nn.Module):
    """FLE: PE(centred pose) + MLP(force), (..., 6) and (..., F) -> (..., dim)."""

    def __init__(self, force_dim: int, dim: int, n_freq: int = 16) -> None:
        super().__init__()
        self.pose_encoding = PoseEncoding(dim, n_freq)
        self.force_mlp = mlp(force_dim, dim, dim)

    def forward(self, pose: Tensor, force: Tensor) -> Tensor:
        return self.pose_encoding(pose) + self.force_mlp(force)


class ParticleEncoder(nn.Module):
    """LESS: a grid of particles with local receptive fields and a shared GRU.

    Args:
        force_dim: F, force features per step (taxels x 3).
        dim: d_z, width of the encoder and the GRU state.
        spacing_mm: particle spacing.
        grid_extent_mm: side of the square the grid covers (centred on ``grid_center_mm``).
        receptive_field_mm: radius beta of each particle's receptive disc.
        max_steps_per_particle: cap on gathered steps per particle (earliest kept); None = no cap.
        n_freq: wavelengths per pose coordinate in the positional encoding.
        grid_center_mm: x, y of the grid centre.
        particles_per_axis: an exact number of particles per axis (even too) instead of the extent's.
    """

    name = "less"
    force_norm = "global"        # the force normalisation it is trained with by default (data.batching)
    fle_module = "fle"           # the name (and state-dict prefix) the paper's FLE is registered under

    def __init__(self, force_dim: int, dim: int = 128, spacing_mm: float = 6.0, grid_extent_mm: float = 60.0,
                 receptive_field_mm: float = 10.0, max_steps_per_particle: int | None = None,
                 n_freq: int = 16, grid_center_mm: tuple[float, float] = (0.0, 0.0),
                 particles_per_axis: int | None = None) -> None:
        super().__init__()
        if not receptive_field_mm > 0:
            raise ValueError(f"receptive_field_mm must be > 0, got {receptive_field_mm}")
        self.settings = {"force_dim": int(force_dim), "dim": int(dim), "spacing_mm": float(spacing_mm),
                         "grid_extent_mm": float(grid_extent_mm),
                         "receptive_field_mm": float(receptive_field_mm),
                         "max_steps_per_particle": None if max_steps_per_particle is None
                         else int(max_steps_per_particle),
                         "n_freq": int(n_freq), "grid_center_mm": [float(c) for c in grid_center_mm],
                         "particles_per_axis": None if particles_per_axis is None
                         else int(particles_per_axis)}
        self.dim = int(dim)
        self.force_dim = int(force_dim)
        self.receptive_field_mm = float(receptive_field_mm)
        self.max_steps = self.settings["max_steps_per_particle"]
        self.add_module(self.fle_module, ForceLocationEncoder(force_dim, dim, n_freq))
        self.gru = nn.GRU(dim, dim, batch_first=True)
        self.register_buffer("xy_mm", self._grid(), persistent=False)

    def _grid(self) -> Tensor:
        s = self.settings
        return particle_grid(s["grid_extent_mm"], s["spacing_mm"], tuple(s["grid_center_mm"]),
                             s["particles_per_axis"])

    def config(self) -> dict:
        """Constructor arguments plus ``name``: ``ENCODERS[c.pop('name')](**c)`` rebuilds the encoder."""
        return {"name": self.name, **copy.deepcopy(self.settings)}

    def with_grid(self, extent_mm: float, center_xy_mm: tuple[float, float] | None = None) -> ParticleEncoder:
        """A copy over a grid of another extent (and centre), same spacing and weights."""
        kwargs = copy.deepcopy(self.settings)
        kwargs["grid_extent_mm"], kwargs["particles_per_axis"] = float(extent_mm), None
        if center_xy_mm is not None:
            kwargs["grid_center_mm"] = [float(c) for c in center_xy_mm]
        other = type(self)(**kwargs)
        other.load_state_dict(self.state_dict())
        other.train(self.training)
        return other.to(device=self.xy_mm.device, dtype=next(self.parameters()).dtype)

    def force_decoder(self) -> nn.Module:
        """The SSL force decoder that pairs with this encoder (a fresh one)."""
        return ForceDecoder(self.force_dim, self.dim, self.settings["n_freq"])

    @property
    def n_particles(self) -> int:
        return int(self.xy_mm.shape[0])

    def _gather(self, batch: Batch) -> SeenRows:
        """The receptive-field gather and its seen (batch, particle) rows, poses centred."""
        xy = self.xy_mm.to(batch.pose.dtype)
        g = gather_receptive_field(batch.pose[..., :2], batch.valid, xy, self.receptive_field_mm,
                                   self.max_steps)
        bi, pi = g.seen.nonzero(as_tuple=True)
        index = g.index[bi, pi]                                      # (N, C)
        shift = torch.zeros(pi.shape[0], 1, POSE_DIM, dtype=batch.pose.dtype, device=batch.pose.device)
        shift[:, 0, :2] = xy[pi]
        return SeenRows(gathered=g, batch_index=bi, particle_index=pi, step_index=index,
                        pose=batch.pose[bi[:, None], index] - shift, mask=g.mask[bi, pi])

    def gather_sequence(self, batch: Batch) -> ParticleSequence:
        """Every seen particle's gathered steps, without states (``z`` None; see :meth:`states_at`)."""
        rows = self._gather(batch)
        bi, g = rows.batch_index, rows.gathered
        return ParticleSequence(batch_index=bi, particle_index=rows.particle_index, z=None, pose=rows.pose,
                                force=batch.force[bi[:, None], rows.step_index], mask=rows.mask,
                                count=rows.count, shape=(int(g.count.shape[0]), int(g.count.shape[1])),
                                xy_mm=self.xy_mm.to(batch.pose.dtype))

    def states_at(self, batch: Batch, seq: ParticleSequence, at: Tensor | None = None) -> Tensor:
        """GRU states of :meth:`gather_sequence`'s rows: (N, C, d_z) after every slot, or (N, k, d_z) after
        the slots ``at`` (N, k), each below its row's count (the recurrence stops at a row's last one)."""
        real = self.fle(seq.pose[seq.mask], seq.force[seq.mask])      # inputs of real steps only
        z = self._run_gru(real.new_zeros(*seq.mask.shape, real.shape[-1]).index_put((seq.mask,), real),
                          seq.count)
        return z if at is None else z.gather(1, at[..., None].expand(-1, -1, z.shape[-1]))

    def encode_sequence(self, batch: Batch) -> ParticleSequence:
        """Run the GRU over every seen particle's gathered steps (see :class:`ParticleSequence`)."""
        seq = self.gather_sequence(batch)
        seq.z = self.states_at(batch, seq)
        return seq

    def _run_gru(self, x: Tensor, count: Tensor) -> Tensor:
        """GRU over (N, C, dim) inputs, each row only up to its ``count`` real steps (inputs past it are
        zeros and never read; see :func:`~lesscli.models.recurrence.ragged_gru`).

        Returns (N, C, dim) states; slots past a row's count are zeros.
        """
        return ragged_gru(x, count, self.gru)

    def gru_step(self, x: Tensor, h: Tensor) -> Tensor:
        """One step of the shared GRU as a cell: inputs x and states h, (N, d_z) each -> new states."""
        gru = self.gru
        return torch.gru_cell(x, h, gru.weight_ih_l0, gru.weight_hh_l0, gru.bias_ih_l0, gru.bias_hh_l0)

    def forward(self, batch: Batch) -> ParticleStates:
        """Batch -> ParticleStates with z (B, P, d_z)."""
        return self.encode_sequence(batch).final_states()


class GlobalEncoder(ParticleEncoder):
    """GLOBAL baseline: the same encoder over the whole sequence, no filtering, no centring.

    One state per scan (P = 1, particle at x = y = 0, unbounded receptive field).

    Args:
        force_dim: F, force features per step.
        dim: d_z.
        max_steps_per_particle: cap on steps (earliest kept); None = no cap.
        n_freq: wavelengths per pose coordinate.
    """

    name = "global"

    def __init__(self, force_dim: int, dim: int = 128, max_steps_per_particle: int | None = None,
                 n_freq: int = 16, **_ignored) -> None:
        super().__init__(force_dim, dim=dim, spacing_mm=1.0, grid_extent_mm=0.0, receptive_field_mm=math.inf,
                         max_steps_per_particle=max_steps_per_particle, n_freq=n_freq)
        self.settings = {k: self.settings[k]
                         for k in ("force_dim", "dim", "max_steps_per_particle", "n_freq")}

    def _grid(self) -> Tensor:
        return torch.zeros(1, 2)

    def with_grid(self, extent_mm: float, center_xy_mm: tuple[float, float] | None = None) -> GlobalEncoder:
        """GLOBAL has one state whatever the phantom size: a copy of itself."""
        return copy.deepcopy(self)
