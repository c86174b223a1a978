"""Switchable simulator effects, one module each, imported only when a scene enables them.

Each module exposes ``DEFAULTS`` (parameter names and default values; a scene may set only these)
and ``stages(params) -> tuple[Stage, ...]``. The order here is the order of stages that share a
pipeline slot. Module import happens in ``load_effect``; nothing here imports an effect module.
"""

from __future__ import annotations

import importlib
from types import ModuleType

EFFECTS: dict[str, str] = {          # scene name -> module under lesscli.sim.effects
    "variability": "variability",    # modulus/thickness jitter (phantom), stiffness texture (force)
    "tilt": "tilt",                  # mount tilt/yaw error of the pad, small-slope validity check
    "viscoelastic": "viscoelastic",  # Prony-series relaxation per taxel
    "shear": "shear",                # bristle (stick-slip) friction per taxel, Poisson shear
    "sensor": "sensor",              # per-taxel gain, crosstalk, saturation, counts
    "noise": "noise",                # white noise, drift, offsets, timestamp jitter, baseline removal
    "pose": "pose_tracking",         # robot or hand-held pose tracking error
}


def load_effect(name: str) -> ModuleType:
    """Import the module of effect ``name`` (a key of EFFECTS)."""
    return importlib.import_module(f"lesscli.sim.effects.{EFFECTS[name]}")
