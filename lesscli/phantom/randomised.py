"""The ``random`` phantom family: single-inclusion training inserts with randomised geometry and materials.

The catalogues (``lesscli.phantom.catalogue``) place every inclusion 5-13 mm from the centre at one
depth with fixed moduli; a model trained on them can learn the layout instead of reading the touch.
Training data therefore comes from this family, and the catalogues stay for evaluation.

Each insert is drawn from its own stream, spawned from the family generator, in a fixed order
(:func:`random_insert`); every parameter is drawn for every insert, so changing ``empty_share`` only
changes which inserts are empty, and ``count = 3`` gives the first three inserts of ``count = 48``.
Names are ``R<index>s<seed>`` (``R0s7``: the first insert drawn with seed 7), so families of different
seeds merge without clashes; a name identifies an insert only together with the ranges it was drawn
from (a scan set's meta records its scene).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, fields, replace

import numpy as np

from lesscli.errors import DataError
from lesscli.phantom.catalogue import hanging
from lesscli.phantom.geometry import (
    FILLING_DEFAULT,
    INCLUSION_DEFAULT,
    SKIN_DEFAULT,
    Phantom,
    Sphere,
    _check_keys,
)

STREAM_KEY = zlib.crc32(b"phantoms-random")   # keeps the family's draws apart from the simulator's streams
CANDIDATES = 16                                # centre candidates drawn per rejection round
RANGE_KEYS = ("diameter_mm", "gap_below_skin_mm", "filling_kpa", "inclusion_kpa", "skin_kpa")
MAY_BE_ZERO = ("gap_below_skin_mm",)           # ranges whose low end may be 0 (others must be > 0)
_R = math.sqrt(0.5)


@dataclass(frozen=True)
class RandomRanges:
    """What the ``random`` family draws from; ranges are (low, high), a degenerate range fixes the value.

    Attributes:
        count: number of inserts.
        seed: seed of the family generator (``family_generator``); part of every name.
        empty_share: probability that an insert has no inclusion.
        diameter_mm: inclusion diameter range.
        gap_below_skin_mm: depth range of the sphere's top under the skin.
        edge_margin_mm: smallest distance from the sphere to the octagon's flats and to the base.
        filling_kpa, inclusion_kpa, skin_kpa: Young's modulus ranges (log-uniform).
        width_mm: octagon size across flats (height and skin thickness are the Phantom defaults).
    """

    count: int = 32
    seed: int = 0
    empty_share: float = 0.15
    diameter_mm: tuple[float, float] = (6.0, 16.0)
    gap_below_skin_mm: tuple[float, float] = (0.5, 6.0)
    edge_margin_mm: float = 1.0
    filling_kpa: tuple[float, float] = (10.0, 40.0)
    inclusion_kpa: tuple[float, float] = (150.0, 600.0)
    skin_kpa: tuple[float, float] = (70.0, 130.0)
    width_mm: float = 60.0

    def __post_init__(self) -> None:
        for key in RANGE_KEYS:
            object.__setattr__(self, key, _range(getattr(self, key), key))
        for key, low in (("count", 1), ("seed", 0)):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise DataError(f"{key} must be an integer >= {low}, got {value!r}")
            object.__setattr__(self, key, int(value))
        for key in ("empty_share", "edge_margin_mm", "width_mm"):
            object.__setattr__(self, key, _number(getattr(self, key), key))
        if not 0.0 <= self.empty_share <= 1.0:
            raise DataError(f"empty_share must lie in [0, 1], got {self.empty_share:g}")
        if self.edge_margin_mm < 0:
            raise DataError(f"edge_margin_mm must be >= 0, got {self.edge_margin_mm:g}")
        if self.width_mm <= 0:
            raise DataError(f"width_mm must be positive, got {self.width_mm:g}")
        self._check_fits()

    def _check_fits(self) -> None:
        body, margin = self.template(), self.edge_margin_mm
        widest, deepest_gap = self.diameter_mm[1], self.gap_below_skin_mm[1]
        free_mm = body.apothem_mm - margin
        if widest / 2 > free_mm:
            raise DataError(f"diameter_mm: {widest:g} mm does not fit in the {self.width_mm:g} mm insert "
                            f"with edge_margin_mm {margin:g} (at most {2 * free_mm:g})")
        deepest_mm = body.skin_thickness_mm + deepest_gap + widest + margin
        if deepest_mm > body.height_mm:
            raise DataError(f"gap_below_skin_mm: a {widest:g} mm sphere {deepest_gap:g} mm under the skin "
                            f"reaches {deepest_mm:g} mm (with edge_margin_mm) below the top, "
                            f"past the {body.height_mm:g} mm base")

    def template(self) -> Phantom:
        """The empty insert every member starts from (``width_mm``, default height, skin and pillar)."""
        return Phantom("template", width_mm=self.width_mm)

    def to_dict(self) -> dict:
        """A JSON/TOML-ready dict of the ranges (``from_dict`` inverts it)."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict, where: str = "random") -> RandomRanges:
        """Ranges from a table; a number for a range means [v, v]. Errors name ``where`` and the key."""
        _check_keys(d, {f.name for f in fields(cls)}, where)
        try:
            return cls(**d)
        except DataError as exc:
            raise DataError(f"{where}: {exc}") from None


def _number(value, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not math.isfinite(value):
        raise DataError(f"{key} must be a finite number, got {value!r}")
    return float(value)


def _range(value, key: str) -> tuple[float, float]:
    """(low, high) from a number or a pair; low <= high, > 0 (>= 0 where allowed)."""
    pair = value if isinstance(value, (list, tuple)) else (value, value)
    if len(pair) != 2:
        raise DataError(f"{key} must be [low, high] or one number, got {value!r}")
    low, high = (_number(v, key) for v in pair)
    if low > high:
        raise DataError(f"{key}: low {low:g} is above high {high:g}")
    if low < 0 or (low == 0 and key not in MAY_BE_ZERO):
        need = ">= 0" if key in MAY_BE_ZERO else "positive"
        raise DataError(f"{key} must be {need}, got [{low:g}, {high:g}]")
    return low, high


def family_generator(seed: int) -> np.random.Generator:
    """The generator of the family with ``seed`` (its own stream, apart from the simulator's)."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(STREAM_KEY,))))


def wall_distance_mm(phantom: Phantom, x_mm, y_mm) -> np.ndarray:
    """Distance from (x, y) to the octagon's nearest flat, mm (negative outside); arrays broadcast."""
    x, y = np.abs(np.asarray(x_mm, dtype=np.float64)), np.abs(np.asarray(y_mm, dtype=np.float64))
    return phantom.apothem_mm - np.maximum(np.maximum(x, y), (x + y) * _R)


def _centre_xy(body: Phantom, room_mm: float, rng: np.random.Generator) -> tuple[float, float]:
    """A point uniform over the octagon whose flats lie ``room_mm`` inside the body's (rejection sampling)."""
    reach = body.apothem_mm - room_mm
    while True:
        xy = rng.uniform(-reach, reach, size=(CANDIDATES, 2))
        ok = np.flatnonzero(wall_distance_mm(body, xy[:, 0], xy[:, 1]) >= room_mm)
        if ok.size:
            return float(xy[ok[0], 0]), float(xy[ok[0], 1])


def _log_uniform(bounds: tuple[float, float], rng: np.random.Generator) -> float:
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


def random_insert(ranges: RandomRanges, name: str, rng: np.random.Generator) -> Phantom:
    """One member of the family, drawn from ``rng`` in this order:

    - empty with probability ``empty_share`` (no inclusion, no pillar);
    - inclusion diameter uniform in ``diameter_mm``;
    - depth: the sphere's top lies ``gap_below_skin_mm`` (uniform) under the skin;
    - centre uniform over the whole insert such that the sphere keeps ``edge_margin_mm`` from every flat
      of the octagon (it lies fully in the filling region), found by rejection sampling;
    - moduli log-uniform (stiffness contrasts are ratios) in ``skin_kpa``, ``filling_kpa`` and
      ``inclusion_kpa``; the pillar keeps the catalogue material, and the inclusion hangs on a pillar
      down to the base, as in the catalogue (``catalogue.hanging``).
    """
    body = ranges.template()
    empty = rng.random() < ranges.empty_share
    radius = rng.uniform(*ranges.diameter_mm) / 2
    gap = rng.uniform(*ranges.gap_below_skin_mm)
    x, y = _centre_xy(body, radius + ranges.edge_margin_mm, rng)
    skin, filling, inclusion = (replace(m, youngs_kpa=_log_uniform(bounds, rng)) for m, bounds in (
        (SKIN_DEFAULT, ranges.skin_kpa), (FILLING_DEFAULT, ranges.filling_kpa),
        (INCLUSION_DEFAULT, ranges.inclusion_kpa)))
    spheres = [] if empty else [Sphere((x, y, -(body.skin_thickness_mm + gap + radius)), radius)]
    inclusions, pillars = hanging(spheres)
    return replace(body, name=name, skin=skin, filling=filling, inclusion=inclusion, inclusions=inclusions,
                   pillars=pillars, _cache={})


def random_family(ranges: RandomRanges, rng: np.random.Generator) -> list[Phantom]:
    """``ranges.count`` inserts named ``R<index>s<ranges.seed>``, each from a stream spawned off ``rng``.

    Args:
        ranges: what to draw from.
        rng: the family generator, normally ``family_generator(ranges.seed)`` (the seed is in the names).

    Returns:
        Phantoms at orientation 0, deterministic for the state of ``rng``.
    """
    streams = rng.spawn(ranges.count)
    return [random_insert(ranges, f"R{i}s{ranges.seed}", stream) for i, stream in enumerate(streams)]


def random_set(ranges: RandomRanges) -> list[Phantom]:
    """The family of ``ranges`` drawn with its own seed (used by scenes and ``less phantom --set random``)."""
    return random_family(ranges, family_generator(ranges.seed))
