"""Phantom geometry: an octagonal insert with a silicone skin over a filling, spherical inclusions on pillars.

Phantom frame: origin at the centre of the insert's top surface, x/y in that plane, z up; the body
occupies z in [-height_mm, 0]. Lengths are in mm, moduli in kPa. The octagon has flats normal to
x, y and the two diagonals, ``width_mm`` across flats. Orientation k means the inner geometry
(inclusions, pillars) is rotated by +k * 45 degrees about z (counter-clockwise seen from above,
x towards y); the octagon itself is invariant under that rotation.

Region priority where parts overlap: inclusion > pillar > skin > filling. Labels use the codes of
``lesscli.io.labels`` (0 background, 1 insert incl. skin, 2 pillar, 3 inclusion).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from lesscli.errors import DataError, did_you_mean
from lesscli.io.labels import BACKGROUND, INCLUSION, INSERT, PILLAR, LabelVolume

SCHEMA, VERSION = "less.phantom", 1
SPEC_ONLY_KEYS = ("schema", "version", "label")   # spec-file keys that are not geometry (label = its grid)
ORIENTATIONS = 8
STEP_RAD = 2 * math.pi / ORIENTATIONS
BOUNDARY_EPS_MM = 1e-9          # points this close outside a boundary still count as inside
COORD_DECIMALS = 9              # rotated coordinates are rounded to 1e-9 mm so hashes are stable
DEFAULT_LABEL_SHAPE = (26, 128, 128)
DEFAULT_LABEL_SPACING_MM = (0.9, 0.4774, 0.4774)

# Material index codes returned by Phantom.material_index.
OUTSIDE, SKIN, FILLING, PILLAR_MAT, INCLUSION_MAT = range(5)

_R = math.sqrt(0.5)
_COS = (1.0, _R, 0.0, -_R, -1.0, -_R, 0.0, _R)   # exact cos/sin of k * 45 deg
_SIN = (0.0, _R, 1.0, _R, 0.0, -_R, -1.0, -_R)


@dataclass(frozen=True)
class Material:
    """An isotropic linear-elastic material: Young's modulus in kPa and Poisson's ratio."""

    name: str
    youngs_kpa: float
    poisson: float = 0.45

    def __post_init__(self) -> None:
        if not (math.isfinite(self.youngs_kpa) and self.youngs_kpa > 0):
            raise DataError(f"material '{self.name}': youngs_kpa must be positive, got {self.youngs_kpa}")
        if not (-1.0 < self.poisson < 0.5):
            raise DataError(f"material '{self.name}': poisson must lie in (-1, 0.5), got {self.poisson}")


@dataclass(frozen=True)
class Sphere:
    """A spherical inclusion: centre (x, y, z) mm in the phantom frame and radius mm."""

    center_mm: tuple[float, float, float]
    radius_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_mm", tuple(float(c) for c in self.center_mm))
        object.__setattr__(self, "radius_mm", float(self.radius_mm))
        if len(self.center_mm) != 3 or not all(map(math.isfinite, self.center_mm)):
            raise DataError(f"sphere: center_mm must be 3 finite numbers, got {self.center_mm}")
        if not (math.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise DataError(f"sphere at {self.center_mm}: radius_mm must be positive, got {self.radius_mm}")


@dataclass(frozen=True)
class Pillar:
    """A vertical cylinder from the base (z = -height) up to ``z_top_mm``, centred at (x, y)."""

    x_mm: float
    y_mm: float
    z_top_mm: float
    radius_mm: float

    def __post_init__(self) -> None:
        for key in ("x_mm", "y_mm", "z_top_mm", "radius_mm"):
            object.__setattr__(self, key, float(getattr(self, key)))
        if not all(map(math.isfinite, (self.x_mm, self.y_mm, self.z_top_mm))):
            raise DataError(f"pillar: coordinates must be finite, got {self}")
        if not (math.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise DataError(f"pillar at ({self.x_mm}, {self.y_mm}): radius_mm must be positive")


SKIN_DEFAULT = Material("ecoflex-skin", 100.0)
FILLING_DEFAULT = Material("hydrogel", 30.0)
INCLUSION_DEFAULT = Material("dragon-skin", 300.0)
PILLAR_DEFAULT = Material("pillar-silicone", 300.0)


def _rotate_xy(x: float, y: float, k: int) -> tuple[float, float]:
    c, s = _COS[k % ORIENTATIONS], _SIN[k % ORIENTATIONS]
    return round(c * x - s * y, COORD_DECIMALS) + 0.0, round(s * x + c * y, COORD_DECIMALS) + 0.0


@dataclass(frozen=True)
class Phantom:
    """One insert (see the module docstring for frame and conventions).

    Attributes:
        name: insert name, e.g. ``St12C13``.
        width_mm: octagon size across flats.
        height_mm: body height; the body spans z in [-height_mm, 0].
        skin_thickness_mm: silicone skin on top, z in [-skin_thickness_mm, 0].
        skin, filling, inclusion, pillar: materials of the four regions.
        inclusions: spheres (already rotated to ``orientation``).
        pillars: pillar cylinders (already rotated to ``orientation``).
        orientation: k, geometry rotated by k * 45 degrees about z.
    """

    name: str
    width_mm: float = 60.0
    height_mm: float = 30.0
    skin_thickness_mm: float = 2.0
    skin: Material = SKIN_DEFAULT
    filling: Material = FILLING_DEFAULT
    inclusion: Material = INCLUSION_DEFAULT
    pillar: Material = PILLAR_DEFAULT
    inclusions: tuple[Sphere, ...] = ()
    pillars: tuple[Pillar, ...] = ()
    orientation: int = 0
    _cache: dict = field(default_factory=dict, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "inclusions", tuple(self.inclusions))
        object.__setattr__(self, "pillars", tuple(self.pillars))
        for key in ("width_mm", "height_mm", "skin_thickness_mm"):
            object.__setattr__(self, key, float(getattr(self, key)))
        for key in ("width_mm", "height_mm"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"phantom '{self.name}': {key} must be positive, got {value}")
        if not (0 <= self.skin_thickness_mm < self.height_mm):
            raise DataError(f"phantom '{self.name}': skin_thickness_mm must lie in [0, height_mm), "
                            f"got {self.skin_thickness_mm}")
        if int(self.orientation) != self.orientation:
            raise DataError(f"phantom '{self.name}': orientation must be an integer 0..7")
        object.__setattr__(self, "orientation", int(self.orientation) % ORIENTATIONS)

    # ------------------------------------------------------------------------------------- outline

    @property
    def apothem_mm(self) -> float:
        """Distance from the centre to each flat of the octagon."""
        return self.width_mm / 2.0

    def inside_outline(self, x_mm, y_mm) -> np.ndarray:
        """True where (x, y) lies inside the octagon (boundary included); arrays broadcast."""
        x, y = np.abs(np.asarray(x_mm, dtype=np.float64)), np.abs(np.asarray(y_mm, dtype=np.float64))
        a = self.apothem_mm + BOUNDARY_EPS_MM
        return (x <= a) & (y <= a) & ((x + y) * _R <= a)

    def outline_xy(self) -> np.ndarray:
        """(8, 2) octagon vertices in mm, counter-clockwise from the first one above the +x axis."""
        radius = self.apothem_mm / math.cos(math.pi / 8)
        ang = math.pi / 8 + STEP_RAD * np.arange(ORIENTATIONS)
        return np.stack([radius * np.cos(ang), radius * np.sin(ang)], axis=1)

    # ------------------------------------------------------------------------------------- regions

    def _points(self, points_mm: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_mm, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points_mm must have shape (n, 3), got {pts.shape}")
        return pts

    def inside_body(self, points_mm: np.ndarray) -> np.ndarray:
        """(n,) bool: inside the octagonal prism z in [-height_mm, 0]."""
        p = self._points(points_mm)
        z = p[:, 2]
        return self.inside_outline(p[:, 0], p[:, 1]) & (z <= BOUNDARY_EPS_MM) & \
            (z >= -self.height_mm - BOUNDARY_EPS_MM)

    def inclusion_sdf_mm(self, points_mm: np.ndarray) -> np.ndarray:
        """(n,) signed distance to the union of inclusion spheres, mm (negative inside; +inf if none)."""
        p = self._points(points_mm)
        out = np.full(p.shape[0], np.inf)
        for s in self.inclusions:
            out = np.minimum(out, np.linalg.norm(p - np.asarray(s.center_mm), axis=1) - s.radius_mm)
        return out

    def _in_pillars(self, p: np.ndarray) -> np.ndarray:
        hit = np.zeros(p.shape[0], dtype=bool)
        for c in self.pillars:
            r2 = (p[:, 0] - c.x_mm) ** 2 + (p[:, 1] - c.y_mm) ** 2
            hit |= (r2 <= c.radius_mm ** 2 + BOUNDARY_EPS_MM) & (p[:, 2] <= c.z_top_mm + BOUNDARY_EPS_MM)
        return hit

    def material_index(self, points_mm: np.ndarray) -> np.ndarray:
        """(n,) int8 material codes: OUTSIDE 0, SKIN 1, FILLING 2, PILLAR_MAT 3, INCLUSION_MAT 4."""
        p = self._points(points_mm)
        body = self.inside_body(p)
        out = np.where(body, FILLING, OUTSIDE).astype(np.int8)
        if self.skin_thickness_mm > 0:
            out[body & (p[:, 2] >= -self.skin_thickness_mm - BOUNDARY_EPS_MM)] = SKIN
        out[body & self._in_pillars(p)] = PILLAR_MAT
        out[body & (self.inclusion_sdf_mm(p) <= BOUNDARY_EPS_MM)] = INCLUSION_MAT
        return out

    def materials(self) -> tuple[Material | None, Material, Material, Material, Material]:
        """Materials indexed by the codes of ``material_index`` (None for OUTSIDE)."""
        return (None, self.skin, self.filling, self.pillar, self.inclusion)

    def classify(self, points_mm: np.ndarray) -> np.ndarray:
        """(n, 3) x, y, z mm -> (n,) uint8 label codes 0..3 (skin counts as insert)."""
        codes = np.array([BACKGROUND, INSERT, INSERT, PILLAR, INCLUSION], dtype=np.uint8)
        return codes[self.material_index(points_mm)]

    def youngs_kpa(self, points_mm: np.ndarray) -> np.ndarray:
        """(n, 3) x, y, z mm -> (n,) Young's modulus in kPa; 0 outside the body."""
        table = np.array([0.0] + [m.youngs_kpa for m in self.materials()[1:]])
        return table[self.material_index(points_mm)]

    def poisson(self, points_mm: np.ndarray) -> np.ndarray:
        """(n, 3) -> (n,) Poisson's ratio; 0 outside the body."""
        table = np.array([0.0] + [m.poisson for m in self.materials()[1:]])
        return table[self.material_index(points_mm)]

    # ------------------------------------------------------------------------------------- transforms

    def rotated(self, k: int) -> Phantom:
        """This insert at orientation ``k`` (absolute: geometry rotated by k * 45 deg from orientation 0)."""
        delta = (int(k) - self.orientation) % ORIENTATIONS
        if delta == 0:
            return self
        spheres = tuple(Sphere((*_rotate_xy(s.center_mm[0], s.center_mm[1], delta), s.center_mm[2]),
                               s.radius_mm)
                        for s in self.inclusions)
        pillars = tuple(Pillar(*_rotate_xy(c.x_mm, c.y_mm, delta), c.z_top_mm, c.radius_mm)
                        for c in self.pillars)
        return replace(self, inclusions=spheres, pillars=pillars, orientation=int(k) % ORIENTATIONS,
                       _cache={})

    def label_volume(self, shape: tuple[int, int, int] = DEFAULT_LABEL_SHAPE,
                     spacing_mm: tuple[float, float, float] = DEFAULT_LABEL_SPACING_MM) -> LabelVolume:
        """Rasterise the labels at voxel centres on a grid centred on x = y = 0, top slice at z = 0.

        Args:
            shape: (D, H, W) voxels along z, y, x.
            spacing_mm: (dz, dy, dx) in mm.

        Returns:
            LabelVolume with origin (-(D-1) dz, -(H-1)/2 dy, -(W-1)/2 dx), named ``<name>_<orientation>``.
        """
        origin = label_grid_origin(shape, spacing_mm)
        axes = [origin[a] + spacing_mm[a] * np.arange(shape[a]) for a in range(3)]
        y, x = np.meshgrid(axes[1], axes[2], indexing="ij")
        data = np.empty(shape, dtype=np.uint8)
        for k, z in enumerate(axes[0]):  # slice by slice keeps memory small on big grids
            pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
            data[k] = self.classify(pts).reshape(x.shape)
        return LabelVolume(data, origin, spacing_mm, f"{self.name}_{self.orientation}")

    # ------------------------------------------------------------------------------------- serialisation

    def to_dict(self) -> dict:
        """A JSON/TOML-ready dict (``from_dict`` inverts it)."""
        return {
            "schema": SCHEMA, "version": VERSION, "name": self.name,
            "width_mm": float(self.width_mm), "height_mm": float(self.height_mm),
            "skin_thickness_mm": float(self.skin_thickness_mm), "orientation": self.orientation,
            **{key: _material_dict(getattr(self, key)) for key in ("skin", "filling", "inclusion", "pillar")},
            "inclusions": [{"center_mm": list(s.center_mm), "radius_mm": float(s.radius_mm)}
                           for s in self.inclusions],
            "pillars": [{"x_mm": float(c.x_mm), "y_mm": float(c.y_mm), "z_top_mm": float(c.z_top_mm),
                         "radius_mm": float(c.radius_mm)} for c in self.pillars],
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "phantom") -> Phantom:
        """Build a Phantom from ``to_dict`` output (or a spec written by ``less phantom``).

        Unknown keys raise DataError naming ``where`` and suggesting the closest valid key.
        """
        if not isinstance(d, dict):
            raise DataError(f"{where}: a phantom must be a table/object, got {type(d).__name__}")
        if d.get("schema", SCHEMA) != SCHEMA or int(d.get("version", VERSION)) != VERSION:
            raise DataError(f"{where}: schema {d.get('schema')!r} version {d.get('version')!r}, "
                            f"expected {SCHEMA} version {VERSION}")
        allowed = {f.name for f in fields(cls) if not f.name.startswith("_")} | set(SPEC_ONLY_KEYS)
        _check_keys(d, allowed, where)
        if "name" not in d:
            raise DataError(f"{where}: missing 'name'")
        kwargs = {k: v for k, v in d.items() if k not in SPEC_ONLY_KEYS}
        try:
            for key in ("skin", "filling", "inclusion", "pillar"):
                if key in kwargs:
                    _check_keys(kwargs[key], {"name", "youngs_kpa", "poisson"}, f"{where}.{key}")
                    kwargs[key] = Material(**kwargs[key])
            kwargs["inclusions"] = tuple(_sphere(s, f"{where}.inclusions[{i}]")
                                         for i, s in enumerate(kwargs.get("inclusions", ())))
            kwargs["pillars"] = tuple(_pillar(c, f"{where}.pillars[{i}]")
                                      for i, c in enumerate(kwargs.get("pillars", ())))
            return cls(**kwargs)
        except DataError as exc:
            msg = str(exc)
            raise DataError(msg if msg.startswith(where) else f"{where}: {msg}") from None
        except KeyError as exc:
            raise DataError(f"{where}: missing key {exc}") from None
        except (TypeError, ValueError) as exc:
            raise DataError(f"{where}: invalid phantom ({exc})") from None

    def content_hash(self) -> str:
        """SHA-1 of geometry, materials and orientation (the name is excluded), for caches."""
        if "hash" not in self._cache:
            d = self.to_dict()
            d.pop("name")
            text = json.dumps(d, sort_keys=True, separators=(",", ":"))
            self._cache["hash"] = hashlib.sha1(text.encode()).hexdigest()
        return self._cache["hash"]


def label_grid_origin(shape: tuple[int, int, int], spacing_mm: tuple[float, float, float]) -> np.ndarray:
    """(3,) z, y, x origin centring the grid on x = y = 0 with the top slice centre at z = 0."""
    d, h, w = shape
    dz, dy, dx = spacing_mm
    return np.array([-(d - 1) * dz, -(h - 1) / 2 * dy, -(w - 1) / 2 * dx], dtype=np.float64)


def default_label_spacing(width_mm: float) -> tuple[float, float, float]:
    """The default (dz, dy, dx) for an insert ``width_mm`` across: in-plane spacing scales with the width
    (60 mm -> 0.4774 mm, the large 120 mm set -> twice that)."""
    scale = round(width_mm / 60.0, 6)
    dz, dy, dx = DEFAULT_LABEL_SPACING_MM
    return (dz, dy * scale, dx * scale)


def _material_dict(m: Material) -> dict:
    return {"name": m.name, "youngs_kpa": float(m.youngs_kpa), "poisson": float(m.poisson)}


def _check_keys(d: dict, allowed: set[str], where: str) -> None:
    if not isinstance(d, dict):
        raise DataError(f"{where}: expected a table/object, got {type(d).__name__}")
    for key in d:
        if key not in allowed:
            raise DataError(f"{where}: unknown key '{key}'"
                            + did_you_mean(key, allowed, f" (allowed: {', '.join(sorted(allowed))})"))


def _sphere(d: dict, where: str) -> Sphere:
    _check_keys(d, {"center_mm", "radius_mm"}, where)
    return Sphere(tuple(d["center_mm"]), float(d["radius_mm"]))


def _pillar(d: dict, where: str) -> Pillar:
    _check_keys(d, {"x_mm", "y_mm", "z_top_mm", "radius_mm"}, where)
    return Pillar(float(d["x_mm"]), float(d["y_mm"]), float(d["z_top_mm"]), float(d["radius_mm"]))
