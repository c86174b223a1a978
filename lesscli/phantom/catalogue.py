"""Phantom catalogues named like the published inserts, and phantom-set files.

- ``single``: one inclusion, diameters 8-16 mm, radial offsets 5-13 mm, angular family C (inclusion
  at 45 deg from +x) or D (22.5 deg); named ``St<diameter>[C|D]<offset>`` e.g. ``St12C13``.
- ``multiple``: 2-3 separate inclusions, connected chains (overlapping spheres on a line) and curved
  formations (overlapping spheres on an arc); named ``Mu..``, ``Ch..``, ``Cv..``.
- ``large``: base 2x wider in x and y (120 mm across flats), same height, single inclusions of the
  usual sizes at larger offsets; named like ``bst12d30``.

Every inclusion hangs on a thin pillar down to the base; a chain or curve has one pillar per sphere.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

from lesscli.errors import DataError
from lesscli.io.toml_files import read_toml
from lesscli.phantom.geometry import Phantom, Pillar, Sphere

FAMILY_ANGLE_DEG = {"C": 45.0, "D": 22.5}
SINGLE_DIAMETERS_MM = (8, 10, 12, 14, 16)
SINGLE_OFFSETS_MM = (5, 9, 13)
LARGE_OFFSETS_MM = (10, 20, 30)
LARGE_DIAMETERS_MM = (8, 12, 16)
PILLAR_RADIUS_MM = 2.0
GAP_BELOW_SKIN_MM = 1.5       # filling between the skin and the top of an inclusion
LARGE_WIDTH_MM = 120.0


def inclusion_depth_mm(radius_mm: float, skin_thickness_mm: float = 2.0) -> float:
    """z of a sphere centre whose top sits GAP_BELOW_SKIN_MM under the skin."""
    return -(skin_thickness_mm + GAP_BELOW_SKIN_MM + radius_mm)


def hanging(spheres: list[Sphere]) -> tuple[tuple[Sphere, ...], tuple[Pillar, ...]]:
    """The spheres with one pillar under each centre."""
    pillars = tuple(Pillar(s.center_mm[0], s.center_mm[1], s.center_mm[2], PILLAR_RADIUS_MM) for s in spheres)
    return tuple(spheres), pillars


def single_insert(diameter_mm: float, family: str, offset_mm: float, width_mm: float = 60.0,
                  name: str | None = None) -> Phantom:
    """One inclusion of ``diameter_mm`` at ``offset_mm`` from the centre along the family's angle."""
    ang = math.radians(FAMILY_ANGLE_DEG[family.upper()])
    r = diameter_mm / 2
    sphere = Sphere((round(offset_mm * math.cos(ang), 9), round(offset_mm * math.sin(ang), 9),
                     inclusion_depth_mm(r)), r)
    inclusions, pillars = hanging([sphere])
    return Phantom(name or f"St{diameter_mm:g}{family.upper()}{offset_mm:g}", width_mm=width_mm,
                   inclusions=inclusions, pillars=pillars)


def single() -> list[Phantom]:
    """The ``single`` catalogue (30 inserts)."""
    return [single_insert(d, fam, off) for d in SINGLE_DIAMETERS_MM for fam in ("C", "D")
            for off in SINGLE_OFFSETS_MM]


def _chain(name: str, start: tuple[float, float], step: tuple[float, float], count: int,
           radius_mm: float) -> Phantom:
    z = inclusion_depth_mm(radius_mm)
    spheres = [Sphere((start[0] + i * step[0], start[1] + i * step[1], z), radius_mm) for i in range(count)]
    inclusions, pillars = hanging(spheres)
    return Phantom(name, inclusions=inclusions, pillars=pillars)


def _curve(name: str, radius_arc_mm: float, angles_deg: list[float], radius_mm: float) -> Phantom:
    z = inclusion_depth_mm(radius_mm)
    spheres = [Sphere((round(radius_arc_mm * math.cos(math.radians(a)), 9),
                       round(radius_arc_mm * math.sin(math.radians(a)), 9), z), radius_mm)
                       for a in angles_deg]
    inclusions, pillars = hanging(spheres)
    return Phantom(name, inclusions=inclusions, pillars=pillars)


def _separate(name: str, placements: list[tuple[float, float, float]]) -> Phantom:
    spheres = [Sphere((x, y, inclusion_depth_mm(d / 2)), d / 2) for x, y, d in placements]
    inclusions, pillars = hanging(spheres)
    return Phantom(name, inclusions=inclusions, pillars=pillars)


def multiple() -> list[Phantom]:
    """The ``multiple`` catalogue: separate pairs/triples, connected chains, curved formations."""
    return [
        _separate("Mu2St10St12", [(-12.0, 4.0, 10), (11.0, -6.0, 12)]),
        _separate("Mu2St8St16", [(-10.0, -10.0, 8), (9.0, 9.0, 16)]),
        _separate("Mu3St8St10St12", [(-13.0, -6.0, 8), (12.0, -8.0, 10), (0.0, 13.0, 12)]),
        _separate("Mu3St10", [(-12.0, 8.0, 10), (12.0, 8.0, 10), (0.0, -12.0, 10)]),
        _chain("Ch2St10", (-4.0, 0.0), (8.0, 0.0), 2, 5.0),
        _chain("Ch3St8", (-7.0, -7.0), (5.0, 5.0), 3, 4.0),
        _chain("Ch3St10", (-9.0, 5.0), (8.0, 0.0), 3, 5.0),
        _curve("Cv3St8", 12.0, [-35.0, 0.0, 35.0], 4.0),
        _curve("Cv4St8", 14.0, [30.0, 60.0, 90.0, 120.0], 4.0),
        _curve("Cv3St10", 13.0, [150.0, 190.0, 230.0], 5.0),
    ]


def large() -> list[Phantom]:
    """The ``large`` catalogue: 120 mm across flats, single inclusions (named like ``bst12d30``)."""
    return [single_insert(d, fam, off, width_mm=LARGE_WIDTH_MM, name=f"bst{d:g}{fam.lower()}{off:g}")
            for d in LARGE_DIAMETERS_MM for fam in ("C", "D") for off in LARGE_OFFSETS_MM]


CATALOGUES: dict[str, Callable[[], list[Phantom]]] = {"single": single, "multiple": multiple, "large": large}


def load_phantom_file(path: str) -> list[Phantom]:
    """Phantoms from a TOML file (``[[phantom]]`` tables) or a JSON geometry spec (one phantom or a list).

    Raises:
        DataError: missing file, parse error or invalid geometry, naming the file.
    """
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    try:
        if path.endswith(".toml"):
            doc = read_toml(path, "phantom set")
            unknown = set(doc) - {"phantom"}
            if unknown:
                raise DataError(f"{path}: unknown top-level key '{min(unknown)}'; expected [[phantom]] "
                                "tables")
            entries = doc.get("phantom", [])
        else:
            import json

            with open(path, encoding="utf-8") as fh:
                doc = json.load(fh)
            entries = (doc if isinstance(doc, list) else doc.get("phantoms", [doc]) if isinstance(doc, dict)
                       else doc)
    except (ValueError, OSError) as exc:
        raise DataError(f"{path}: cannot parse ({exc})") from None
    if not isinstance(entries, list) or not entries:
        raise DataError(f"{path}: holds no phantoms")
    return [Phantom.from_dict(e, where=f"{path}: phantom {i}") for i, e in enumerate(entries)]


def resolve_set(name_or_path: str) -> list[Phantom]:
    """A catalogue by name, or the phantoms of a file; unknown names suggest the closest catalogue."""
    if name_or_path in CATALOGUES:
        return CATALOGUES[name_or_path]()
    if os.path.splitext(name_or_path)[1] in (".toml", ".json"):
        return load_phantom_file(name_or_path)
    from lesscli.errors import did_you_mean

    raise DataError(f"unknown phantom set '{name_or_path}'"
                    + did_you_mean(name_or_path, CATALOGUES,
                                   f" (choose {', '.join(CATALOGUES)} or a .toml/.json file)"))
