"""Lift configuration (``lift.toml``) and the scissor geometry that maps platform height to screw ticks.

Geometry: ``stages`` stacked scissor pairs with arms of ``arm_length_mm`` (pin to pin). The lead screw
(``lead_mm`` per turn) moves one arm foot horizontally; with the feet ``x`` mm apart the platform sits at
``offset_mm + stages * sqrt(L^2 - x^2)``. Screw ticks count from the lower mechanical stop (the homing
zero, at ``stop_height_mm``); ``direction`` is +1 when positive ticks raise the platform, -1 otherwise.

Every key of ``lift.toml``, with its default: docs/guide/lift.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from lesscli.errors import DataError
from lesscli.hardware.protocol import TICKS_PER_TURN
from lesscli.io.overrides import check_known, resolve_dataclass, set_path
from lesscli.io.toml_files import read_toml

ORIENTATIONS = 8
TICKS_PER_ORIENTATION = TICKS_PER_TURN // ORIENTATIONS  # 45 degrees = 512 ticks


@dataclass(frozen=True)
class ScissorGeometry:
    """Height (mm) <-> screw turns <-> ticks, zero at the lower mechanical stop."""

    arm_length_mm: float = 100.0
    stages: int = 2
    lead_mm: float = 2.0
    offset_mm: float = 20.0
    stop_height_mm: float = 30.0
    direction: int = 1

    @property
    def top_height_mm(self) -> float:
        """Height with the arms vertical (unreachable upper bound)."""
        return self.offset_mm + self.stages * self.arm_length_mm

    def _foot_mm(self, height_mm: float) -> float:
        rise_mm = (height_mm - self.offset_mm) / self.stages
        return math.sqrt(self.arm_length_mm**2 - rise_mm**2)

    def turns_for_height(self, height_mm: float) -> float:
        """Screw turns from the stop to ``height_mm`` (signed by ``direction``)."""
        return self.direction * (self._foot_mm(self.stop_height_mm) - self._foot_mm(height_mm)) / self.lead_mm

    def ticks_for_height(self, height_mm: float) -> float:
        """Encoder ticks from the stop to ``height_mm``."""
        return self.turns_for_height(height_mm) * TICKS_PER_TURN

    def height_for_ticks(self, ticks: float) -> float:
        """Platform height (mm) at ``ticks`` from the stop (NaN beyond the arms' reach)."""
        foot_mm = self._foot_mm(self.stop_height_mm) - self.direction * ticks / TICKS_PER_TURN * self.lead_mm
        if not 0.0 <= foot_mm <= self.arm_length_mm:
            return math.nan
        return self.offset_mm + self.stages * math.sqrt(self.arm_length_mm**2 - foot_mm**2)


@dataclass(frozen=True)
class LiftConfig:
    """Everything ``ScissorLift`` needs; docs/guide/lift.md gives the TOML layout and units."""

    port: str | None = None
    baud: int = 57600
    retries: int = 1
    latency_ms: float = 0.0
    lift_id: int = 1
    lift_velocity: int = 100
    homing_velocity: int = 40
    tolerance_ticks: int = 20
    rotator_id: int = 2
    rotator_velocity: int = 60
    rotator_zero_ticks: int = 0
    geometry: ScissorGeometry = field(default_factory=ScissorGeometry)
    min_height_mm: float = 32.0
    max_height_mm: float = 100.0
    lowered_height_mm: float = 35.0
    raised_height_mm: float = 95.0
    poll_s: float = 0.02
    stall_s: float = 0.5
    timeout_factor: float = 2.0
    timeout_margin_s: float = 2.0
    homing_timeout_s: float = 120.0

    def rotator_goal(self, orientation: int) -> int:
        """Goal_Position (ticks) of the rotator for orientation ``k`` (0..7, 45 degrees each)."""
        return self.rotator_zero_ticks + TICKS_PER_ORIENTATION * orientation

    def validate(self, source: str = "lift config") -> LiftConfig:
        """Check consistency; raises DataError naming ``source`` and the offending keys."""
        g = self.geometry
        problems = []
        if not g.stop_height_mm <= self.min_height_mm <= self.lowered_height_mm:
            problems.append("need stop_height_mm <= min_height_mm <= lowered_height_mm")
        if not self.lowered_height_mm < self.raised_height_mm <= self.max_height_mm:
            problems.append("need lowered_height_mm < raised_height_mm <= max_height_mm")
        if not (g.offset_mm <= g.stop_height_mm and self.max_height_mm < g.top_height_mm):
            problems.append(f"heights must lie in [offset_mm, {g.top_height_mm:g}) (arms' reach)")
        if g.direction not in (1, -1) or g.lead_mm <= 0 or g.stages < 1 or g.arm_length_mm <= 0:
            problems.append("need direction = 1 or -1, lead_mm > 0, stages >= 1, arm_length_mm > 0")
        if not 0 <= self.rotator_zero_ticks <= TICKS_PER_TURN - 1 - (ORIENTATIONS
                                                                     - 1) * TICKS_PER_ORIENTATION:
            problems.append("[rotator] zero_ticks must be in 0..511 so that orientation 7 stays within one "
                            "turn")
        if self.lift_id == self.rotator_id:
            problems.append(f"lift and rotator share id {self.lift_id}")
        if min(self.lift_velocity, self.homing_velocity, self.rotator_velocity) <= 0:
            problems.append("velocities must be > 0")
        if problems:
            raise DataError(f"{source}: " + "; ".join(problems))
        return self


_SECTIONS = {     # lift.toml table -> key -> LiftConfig field
    "bus": {"port": "port", "baud": "baud", "retries": "retries", "latency_ms": "latency_ms"},
    "lift": {"id": "lift_id", "velocity": "lift_velocity", "homing_velocity": "homing_velocity",
             "tolerance_ticks": "tolerance_ticks"},
    "rotator": {"id": "rotator_id", "velocity": "rotator_velocity", "zero_ticks": "rotator_zero_ticks"},
    "geometry": {f.name: f"geometry.{f.name}" for f in fields(ScissorGeometry)},
    "limits": {k: k for k in ("min_height_mm", "max_height_mm", "lowered_height_mm", "raised_height_mm")},
    "timing": {k: k for k in ("poll_s", "stall_s", "timeout_factor", "timeout_margin_s", "homing_timeout_s")},
}


def load_config(path: str | None = None, **overrides) -> LiftConfig:
    """Defaults < ``lift.toml`` (None: none) < non-None ``overrides`` (LiftConfig field names), layered by
    lesscli.io.overrides.

    Raises:
        DataError: unreadable file, unknown section or key, wrong value type, inconsistent values.
    """
    doc: dict = {}
    if path:
        data = read_toml(path, "lift config")
        check_known(data, _SECTIONS, path)
        for section, table in data.items():
            for key, value in table.items():
                set_path(doc, tuple(_SECTIONS[section][key].split(".")), value, path)
    config = resolve_dataclass(LiftConfig, doc, path or "lift config", overrides)
    return config.validate(path or "lift config")
