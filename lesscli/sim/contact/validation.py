"""Closed forms and reference bodies for validating the contact tiers (SIMULATION.md V1-V10).

Units: mm, N; moduli in kPa at the interface, N/mm^2 (MPa) inside the formulas.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

import numpy as np

from lesscli.sim import fem
from lesscli.sim.contact.qp import solve_contact

FLAT_PUNCH_COEF = 1.13


def e_star(e_kpa: float, nu: float) -> float:
    """Plane-strain modulus E / (1 - nu^2), N/mm^2."""
    return e_kpa * fem.KPA_TO_N_MM2 / (1 - nu ** 2)


def hertz_force_n(e_kpa: float, nu: float, radius_mm: float, depth_mm) -> np.ndarray:
    """Rigid sphere on an elastic half-space: F = 4/3 E* sqrt(R) d^1.5, N."""
    d = np.asarray(depth_mm, dtype=np.float64)
    return 4.0 / 3.0 * e_star(e_kpa, nu) * math.sqrt(radius_mm) * np.maximum(d, 0) ** 1.5


def dimitriadis_force_n(e_kpa: float, nu: float, radius_mm: float, depth_mm,
                        thickness_mm: float) -> np.ndarray:
    """Rigid sphere on a layer bonded to a rigid base (Dimitriadis et al. 2002), N."""
    d = np.asarray(depth_mm, dtype=np.float64)
    chi = np.sqrt(radius_mm * np.maximum(d, 0)) / thickness_mm
    a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu ** 2) / (1 - nu)
    b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu ** 2) / (1 - nu)
    pi = math.pi
    corr = (1 - 2 * a0 / pi * chi + 4 * a0 ** 2 / pi ** 2 * chi ** 2
            - 8 / pi ** 3 * (a0 ** 3 + 4 * pi ** 2 / 15 * b0) * chi ** 3
            + 16 * a0 / pi ** 4 * (a0 ** 3 + 3 * pi ** 2 / 5 * b0) * chi ** 4)
    return hertz_force_n(e_kpa, nu, radius_mm, d) * corr


def flat_punch_force_n(e_kpa: float, nu: float, area_mm2: float, depth_mm) -> np.ndarray:
    """Rigid flat punch on a half-space: F ~ 1.13 E* sqrt(A) d, N."""
    return FLAT_PUNCH_COEF * e_star(e_kpa, nu) * math.sqrt(area_mm2) * np.asarray(depth_mm, dtype=np.float64)


@dataclass(frozen=True)
class Block:
    """A reference body with the phantom API: square (or octagonal) outline, horizontal layers, spheres.

    Attributes:
        width_mm: side of the square (across flats for an octagon).
        height_mm: body height, z in [-height_mm, 0].
        layers: ((thickness_mm, youngs_kpa), ...) from the top; the last layer fills to the base.
        spheres: ((x, y, z, radius_mm, youngs_kpa), ...) inclusions.
        poisson: Poisson's ratio of every material.
        octagon: octagonal outline like the phantoms instead of a square.
    """

    width_mm: float = 40.0
    height_mm: float = 20.0
    layers: tuple = ((20.0, 15.0),)
    spheres: tuple = ()
    poisson: float = 0.45
    octagon: bool = False
    name: str = "block"

    @property
    def skin_thickness_mm(self) -> float:
        return float(self.layers[0][0]) if len(self.layers) > 1 else 0.0

    @property
    def filling(self):
        return type("Filling", (), {"poisson": self.poisson})()

    def inside_outline(self, x_mm, y_mm) -> np.ndarray:
        x, y = np.abs(np.asarray(x_mm, dtype=np.float64)), np.abs(np.asarray(y_mm, dtype=np.float64))
        a = self.width_mm / 2 + 1e-9
        inside = (x <= a) & (y <= a)
        return inside & ((x + y) * math.sqrt(0.5) <= a) if self.octagon else inside

    def outline_xy(self) -> np.ndarray:
        a = self.width_mm / 2
        if self.octagon:
            r = a / math.cos(math.pi / 8)
            ang = math.pi / 8 + math.pi / 4 * np.arange(8)
            return np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
        return np.array([[a, a], [-a, a], [-a, -a], [a, -a]])

    def youngs_kpa(self, points_mm: np.ndarray) -> np.ndarray:
        p = np.asarray(points_mm, dtype=np.float64)
        depth = -p[:, 2]
        e = np.full(p.shape[0], float(self.layers[-1][1]))
        top = 0.0
        for thick, mod in self.layers[:-1]:
            e[(depth >= top) & (depth < top + thick)] = mod
            top += thick
        for x, y, z, r, mod in self.spheres:
            e[np.linalg.norm(p - np.array([x, y, z]), axis=1) <= r] = mod
        body = self.inside_outline(p[:, 0], p[:, 1]) & (depth >= -1e-9) & (depth <= self.height_mm + 1e-9)
        return np.where(body, e, 0.0)

    def content_hash(self) -> str:
        text = json.dumps([self.width_mm, self.height_mm, self.layers, self.spheres, self.poisson,
                           self.octagon])
        return hashlib.sha1(text.encode()).hexdigest()


def sphere_indentation_n(e_kpa: float, nu: float, radius_mm: float, depths_mm, height_mm: float,
                         half_width_mm: float, h_fine_mm: float, growth: float = 1.3) -> np.ndarray:
    """Total force of a rigid paraboloid (radius R) pressed into a homogeneous block, by FEM.

    A quarter model (symmetry planes x = 0, y = 0) graded from ``h_fine_mm`` around the contact.
    The gap is the Hertz paraboloid, g = d - r^2 / (2 R), so the result compares to Hertz /
    Dimitriadis directly. Returns (len(depths),) forces, N.
    """
    depths = np.atleast_1d(np.asarray(depths_mm, dtype=np.float64))
    a_max = math.sqrt(radius_mm * depths.max())
    block = Block(2 * half_width_mm, height_mm, ((height_mm, e_kpa),), poisson=nu)
    xs = fem.graded_axis(half_width_mm, h_fine_mm, 1.5 * a_max, growth, h_max_mm=4.0)
    zs = -fem.graded_axis(height_mm, h_fine_mm, 0.5 * a_max, growth, h_max_mm=4.0)[::-1]
    bm = fem.body_mesh(block, xs, xs, zs, symmetry=("x", "y"))
    system = fem.reduce(fem.stiffness(block, bm, nu), bm)
    r2 = (bm.top_xy_mm ** 2).sum(axis=1)
    near = np.nonzero(r2 <= (1.4 * a_max + h_fine_mm) ** 2)[0]
    c, _ = fem.symmetrise(fem.surface_compliance(system, near))
    forces = [4.0 * solve_contact(c, d - r2[near] / (2 * radius_mm)).sum() for d in depths]
    return np.asarray(forces)
