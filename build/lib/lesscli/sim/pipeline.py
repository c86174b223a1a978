"""Compile a scene into an ordered tuple of pure stages and run it on one scan.

Effects absent from the scene (or with ``enabled = false``) are never imported, never run and draw
no random numbers. Every effect, and the motion generator, draws from its own stream
``SeedSequence(seed, spawn_key=(scan_index, crc32(name)))``, so switching one effect on or off never
changes another's noise, and a scan's data does not depend on which shard or worker computes it.
"""

from __future__ import annotations

import zlib
from dataclasses import fields

import numpy as np

from lesscli.sim.core import core_stages
from lesscli.sim.effects import EFFECTS, load_effect
from lesscli.sim.scene import Scene
from lesscli.sim.state import SLOTS, SimState, Stage

_EFFECT_RANK = {name: i for i, name in enumerate(EFFECTS)}


def compile_pipeline(scene: Scene) -> tuple[Stage, ...]:
    """The scene's stages in execution order (slot, then effect registry order).

    Returns:
        A tuple of Stage; core stages (``core:*``) plus those of each enabled effect.
    """
    core = core_stages(scene.contact, scene.motion)
    stages = list(core.values())
    for name, params in scene.effects.items():
        stages.extend(load_effect(name).stages(params))
    order = {slot: i for i, slot in enumerate(SLOTS)}
    return tuple(sorted(stages, key=lambda s: (order[s.slot], _EFFECT_RANK.get(s.effect, -1))))


def stream(seed: int, scan_index: int, name: str) -> np.random.Generator:
    """The random stream of effect ``name`` for scan ``scan_index``."""
    key = zlib.crc32(name.encode())
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(scan_index, key))))


def run_stages(stages: tuple[Stage, ...], state: SimState, check: bool = True) -> SimState:
    """Thread ``state`` through ``stages``; each effect gets one generator for the scan.

    Args:
        check: verify that every stage changed only the fields it declares in ``writes``.
    """
    rngs: dict[str, np.random.Generator] = {}
    for stage in stages:
        rng = rngs.get(stage.effect)
        if rng is None:
            rng = rngs[stage.effect] = stream(state.seed, state.scan_index, stage.effect)
        new = stage.fn(state, stage.params, rng)
        if check:
            _check_writes(stage, state, new)
        state = new
    return state


def _check_writes(stage: Stage, old: SimState, new: SimState) -> None:
    changed = [f.name for f in fields(SimState) if getattr(old, f.name) is not getattr(new, f.name)]
    undeclared = [name for name in changed if name not in stage.writes]
    if undeclared:
        raise RuntimeError(f"stage {stage.name} changed {undeclared} without declaring them in 'writes'")


def initial_state(scene: Scene, scan_index: int, phantom, orientation: int) -> SimState:
    """The state a scan starts from (insert at orientation 0; the scan's rotation is kept apart)."""
    return SimState(scan_index=scan_index, seed=scene.seed, insert=phantom.name, orientation=orientation,
                    phantom=phantom.rotated(0), sensor=scene.sensor)
