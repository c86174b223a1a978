"""Incremental (streaming) imaging: one (pose, force) sample at a time, same result as batch prediction.

:class:`StreamingImager` keeps, per particle, the GRU hidden state and the number of in-field steps it
has seen. A new sample is normalised as in training, tested against every receptive field with the
encoder's own rule, and advances only the particles it reaches (one step of the shared GRU cell, as batch
evaluation steps it); only their patches are re-decoded and swapped on the summed logit canvas
(:class:`PatchCanvas`), so only the pixels under them change. A particle whose count reached
``max_steps_per_particle`` ignores later samples, as the batch encoder keeps the earliest steps, so the
equivalence holds for every prefix. The canvas is float64, so thousands of add-and-subtract updates do
not drift; stream and batch agree to float32 rounding. Decoders without per-particle patches (the GLOBAL
baseline) decode the whole image after each advancing sample (:class:`WholeImage`).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from lesscli.errors import DataError
from lesscli.models.encoders import ParticleStates
from lesscli.models.encoding import POSE_DIM
from lesscli.models.global_decoder import GlobalDecoder
from lesscli.models.particles import in_field
from lesscli.models.patch_decoder import (
    ImageGrid,
    PatchDecoder,
    padded_corners,
    resample_patches,
    target_patch_size,
)

# a pixel counts as uncertain above this share of the maximum entropy ln(C)
UNCERTAIN_SHARE = 0.5


class PatchCanvas:
    """Summed per-particle logit patches on the image grid, updated one particle set at a time.

    Each particle's patch is placed by :func:`place_patches`' rule; only its part on the grid is added
    (a patch wholly off the grid adds nothing), so the canvas is the image itself. With the decoder's
    ``stitch="mean"`` a count of the seen patches per pixel is kept too and the image is the sum divided by
    it; with its neighbour context (``context=k``) the particles whose context reads an advanced one are
    re-decoded too (up to k^2 times as many patches per update).

    Args:
        decoder: the imaging model's PatchDecoder.
        xy_mm: (P, 2) particle positions, mm.
        grid: output grid.
        device: where the canvas lives.
    """

    def __init__(self, decoder: PatchDecoder, xy_mm: Tensor, grid: ImageGrid, device: torch.device) -> None:
        self.decoder, self.grid = decoder, grid
        d, h, w = grid.shape
        raw = (decoder.depth_px, decoder.patch_px, decoder.patch_px)
        self.size = target_patch_size(raw, decoder.patch_spacing_mm, grid)
        ph, pw = self.size[1:]
        row0, col0 = padded_corners(xy_mm, grid, ph, pw)              # place_patches' placement rule
        self.place: list[tuple[tuple, tuple] | None] = []             # per particle: (grid, patch) index
        for r, c in zip((row0 - ph).tolist(), (col0 - pw).tolist()):  # top-left on the grid, may be outside
            rows, cols = (max(r, 0), min(r + ph, h)), (max(c, 0), min(c + pw, w))
            on_grid = rows[0] < rows[1] and cols[0] < cols[1]
            self.place.append(((..., slice(*rows), slice(*cols)),
                               (..., slice(rows[0] - r, rows[1] - r), slice(cols[0] - c, cols[1] - c)))
                              if on_grid else None)
        c, n = decoder.n_classes, xy_mm.shape[0]
        # classes innermost in memory (as the decoder makes patches with channels_last): each slice add
        # runs over whole rows of pw * C values
        self.canvas = torch.zeros(d, h, w, c, dtype=torch.float64, device=device).permute(3, 0, 1, 2)
        self.cache = torch.zeros(n, d, ph, pw, c, dtype=torch.float32, device=device).permute(0, 4, 1, 2, 3)
        self.mean_stitch = getattr(decoder, "stitch", "sum") == "mean"
        self.cover = torch.zeros(h, w, dtype=torch.float64, device=device)       # seen patches per pixel
        self.placed = [False] * n

    def reset(self) -> None:
        self.canvas.zero_()
        self.cache.zero_()
        self.cover.zero_()
        self.placed = [False] * len(self.placed)

    def update(self, particles: Tensor, z: Tensor, hidden: Tensor, seen: Tensor) -> None:
        """Re-decode ``particles`` (k,) from their states ``z`` (k, d_z) and update the canvas.

        With a neighbour context (``decoder.context``) every particle within reach of the convolution
        is re-decoded too, from the whole grid's states ``hidden`` (P, d_z) and ``seen`` (P,)."""
        if self.decoder.context:
            particles = self.within_context(particles, seen)
            z = self.decoder.with_context(hidden[None], seen[None])[0, particles]
        # (k, C, D, ph, pw)
        new = resample_patches(self.decoder.patches(z[None], channels_last=True), self.size)[0]
        for j, p in enumerate(particles.tolist()):
            if self.place[p] is None:
                continue
            on_grid, part = self.place[p]
            patch, old = new[j][part], self.cache[p][part]
            self.canvas[on_grid].add_(patch).sub_(old)
            old.copy_(patch)
            if not self.placed[p]:
                self.cover[on_grid[1:]] += 1.0
                self.placed[p] = True

    def within_context(self, particles: Tensor, seen: Tensor) -> Tensor:
        """(k,) particle indices -> every seen particle whose context convolution reads one of them
        (an unseen particle places no patch)."""
        n, reach = math.isqrt(len(self.placed)), self.decoder.context
        mask = torch.zeros(len(self.placed), device=particles.device)
        mask[particles] = 1.0
        grown = F.max_pool2d(mask.view(1, 1, n, n), reach, stride=1, padding=reach // 2)
        return (grown.reshape(-1).bool() & seen).nonzero()[:, 0]

    def logits(self) -> Tensor:
        """(C, D, H, W) float32 summed logits (0 where no seen particle's patch reaches)."""
        canvas = self.canvas / self.cover.clamp_min(1.0) if self.mean_stitch else self.canvas
        return canvas.to(torch.float32, memory_format=torch.contiguous_format)


class WholeImage:
    """Fallback for decoders without local patches: decode the whole image after each update."""

    def __init__(self, decoder: torch.nn.Module, xy_mm: Tensor, grid: ImageGrid,
                 device: torch.device) -> None:
        self.decoder, self.xy_mm, self.grid = decoder, xy_mm, grid
        self._logits: Tensor | None = None

    def reset(self) -> None:
        self._logits = None

    def update(self, particles: Tensor, z: Tensor, hidden: Tensor, seen: Tensor) -> None:
        self._logits = self.decoder(ParticleStates(z=hidden[None], xy_mm=self.xy_mm, seen=seen[None]),
                                    self.grid)[0]

    def logits(self) -> Tensor:
        return self._logits


# decoder type -> how its logits are maintained
CANVASES: dict[type, type] = {PatchDecoder: PatchCanvas, GlobalDecoder: WholeImage}


class StreamingImager:
    """Incremental imaging with a trained :class:`lesscli.models.imager.Imager`.

    Args:
        imager: encoder (a ParticleEncoder or GlobalEncoder) + decoder; put in evaluation mode.
        norm_stats: the checkpoint's force normalisation statistics.
        grid: output grid (default: the imager's training grid).
        device: torch device (default: where the imager's parameters are).
        defer_decode: a sample only advances GRU states and marks their particles; patches are
            re-decoded (once per particle, batched) when the image is read or :meth:`flush` is called.
            Same images, less work when several samples arrive per displayed frame.
    """

    def __init__(self, imager: torch.nn.Module, norm_stats: dict, grid: ImageGrid | None = None,
                 device: torch.device | str | None = None, defer_decode: bool = False) -> None:
        imager.eval()                  # evaluation mode, as batch prediction
        self.encoder, self.decoder = imager.encoder, imager.decoder
        self.grid = grid or imager.grid
        self.device = torch.device(device) if device is not None else next(imager.parameters()).device
        self.xy_mm = self.encoder.xy_mm.to(self.device, torch.float32)
        self.radius_mm = float(self.encoder.receptive_field_mm)
        self.cap = self.encoder.max_steps
        self.mean = np.asarray(norm_stats["force_mean"], np.float64)
        self.std = np.asarray(norm_stats["force_std"], np.float64)
        canvas_cls = next((v for k, v in CANVASES.items() if isinstance(self.decoder, k)), WholeImage)
        self.canvas = canvas_cls(self.decoder, self.xy_mm, self.grid, self.device)
        n, d = self.xy_mm.shape[0], int(self.encoder.dim)
        self.hidden = torch.zeros(n, d, device=self.device)
        self.count = torch.zeros(n, dtype=torch.long, device=self.device)
        self.dirty = torch.zeros(n, dtype=torch.bool, device=self.device)
        self._valid = torch.ones(1, 1, dtype=torch.bool, device=self.device)     # in_field's step mask
        self.defer_decode = defer_decode
        self.n_steps = 0
        self.reset()

    @property
    def force_dim(self) -> int:
        return int(self.mean.shape[0])

    @property
    def seen(self) -> Tensor:
        """(P,) bool: the particle has seen at least one step."""
        return self.count > 0

    def reset(self) -> None:
        """Forget every sample (a new scan)."""
        self.hidden.zero_()
        self.count.zero_()
        self.dirty.zero_()
        self.n_steps = 0
        self.canvas.reset()
        if isinstance(self.canvas, WholeImage):
            with torch.no_grad():
                self.canvas.update(self.count[:0], self.hidden[:0], self.hidden, self.seen)

    def normalise(self, force: np.ndarray) -> Tensor:
        """Raw force (T, 3) or (T * 3,) in sensor units -> (T * 3,) float32 normalised, as in training."""
        flat = np.asarray(force, np.float64).reshape(-1)
        if flat.shape[0] != self.force_dim:
            raise DataError(f"force has {flat.shape[0]} values, the model expects {self.force_dim} (taxels x "
                            "3)")
        return torch.from_numpy(((flat - self.mean) / self.std).astype(np.float32)).to(self.device)

    def push(self, pose: np.ndarray, force: np.ndarray) -> Tensor:
        """Add one raw sample: pose (6,) x, y, z mm, roll, pitch, yaw rad; force (T, 3) sensor units.

        Returns:
            (k,) long indices of the particles the sample advanced (empty: outside every field or capped).
        """
        pose_t = torch.from_numpy(np.ascontiguousarray(np.asarray(pose).reshape(-1),
                                                       np.float32)).to(self.device)
        if pose_t.shape[0] != POSE_DIM:
            raise DataError(f"pose has {pose_t.shape[0]} values, expected {POSE_DIM} (x, y, z mm, roll, "
                            "pitch, yaw rad)")
        return self.push_normalised(pose_t, self.normalise(force))

    @torch.no_grad()
    def push_normalised(self, pose: Tensor, force: Tensor) -> Tensor:
        """Add one sample already in model units: pose (6,) float32, force (F,) float32 normalised."""
        self.n_steps += 1
        inside = in_field(pose[None, None, :2], self._valid, self.xy_mm, self.radius_mm)[0, :, 0]   # (P,)
        if self.cap is not None:
            inside &= self.count < self.cap
        particles = inside.nonzero()[:, 0]
        if particles.numel() == 0:
            return particles
        shift = torch.zeros(particles.shape[0], POSE_DIM, device=self.device)
        shift[:, :2] = self.xy_mm[particles]
        centred = pose[None] - shift                                               # (k, 6), as batch centres
        x = self.encoder.fle(centred, force[None])                                 # (k, d): one force MLP row
        h = self.encoder.gru_step(x, self.hidden[particles])                      # as batch evaluation steps
        self.hidden[particles] = h
        self.count += inside
        if self.defer_decode:
            self.dirty |= inside
        else:
            self.canvas.update(particles, h, self.hidden, self.seen)
        return particles

    @torch.no_grad()
    def flush(self) -> int:
        """Re-decode the patches of every particle advanced since the last flush; returns how many."""
        particles = self.dirty.nonzero()[:, 0]
        if particles.numel():
            self.canvas.update(particles, self.hidden[particles], self.hidden, self.seen)
            self.dirty.zero_()
        return int(particles.numel())

    @torch.no_grad()
    def prime(self, pose: np.ndarray, force: np.ndarray) -> None:
        """Start from a prefix in one batch pass (e.g. a partial scan), then continue sample by sample.

        Args:
            pose: (n, 6) raw poses; force: (n, T, 3) raw forces. Replaces any earlier samples.
        """
        from lesscli.data.batching import collate, normalise_forces

        n = int(pose.shape[0])
        flat = normalise_forces(force, self.mean, self.std)
        item = {"pose": torch.from_numpy(np.ascontiguousarray(pose, np.float32)),
                "force": torch.from_numpy(flat), "scan_index": 0}
        batch = collate([item]).to(self.device)
        self.reset()
        states = self.encoder(batch)
        inside = in_field(batch.pose[..., :2], batch.valid, self.xy_mm, self.radius_mm)[0].sum(-1)   # (P,)
        self.count.copy_(inside if self.cap is None else inside.clamp(max=self.cap))
        self.hidden.copy_(states.z[0])
        self.n_steps = n
        self.dirty.copy_(self.seen)
        self.flush()

    def logits(self) -> Tensor:
        """(C, D, H, W) float32 logits of the image after the samples so far (flushes deferred decodes).

        Before the first sample nothing is known: all logits 0, uniform probabilities (as
        lesscli.io.predictions.nothing_known), whatever the decoder.
        """
        self.flush()
        logits = self.canvas.logits()
        return torch.zeros_like(logits) if self.n_steps == 0 else logits

    def probs(self) -> np.ndarray:
        """(C, D, H, W) float32 class probabilities."""
        return torch.softmax(self.logits(), dim=0).cpu().numpy()

    def entropy(self) -> np.ndarray:
        """(D, H, W) float32 Shannon entropy in nats (log-softmax, no rounding floor needed)."""
        logp = torch.log_softmax(self.logits(), dim=0)
        return (-(logp.exp() * logp).sum(0)).cpu().numpy()


def entropy_summary(ent: np.ndarray, n_classes: int) -> dict:
    """Entropy statistics: mean/max nats and the share of pixels above ``UNCERTAIN_SHARE * ln(C)``."""
    top = float(np.log(n_classes))
    return {"entropy_mean_nats": float(ent.mean()), "entropy_max_nats": float(ent.max()),
            "uncertain_fraction": float((ent > UNCERTAIN_SHARE * top).mean())}
