"""Tier 2 ``green`` (default): FEM surface compliance once per phantom, a contact QP per step.

Precompute: the body is meshed (``lesscli.sim.fem``), the stiffness assembled in float64 and the
top-surface compliance C (u = C p, vertical nodal forces to vertical displacements) obtained by an
exact elimination of the node layers; C is cached on disk by the phantom's content hash.

Per step: the surface nodes under the pad form the candidate set; their penetration g into the
undeformed surface and the compliance M = C + s I (s: the sensor skin's series compliance per
node, which bounds the rim singularity of a flat punch) define the unilateral QP of
``lesscli.sim.contact.qp``. Nodal forces are shared among taxel cells by the overlap of each
node's tributary square with the cells.
"""

from __future__ import annotations

import numpy as np

from lesscli.errors import SimulationError
from lesscli.geometry.rotations import euler_to_matrix
from lesscli.sim import fem, kinematics
from lesscli.sim.contact import cache
from lesscli.sim.contact.base import ContactModel, check_params
from lesscli.sim.contact.qp import solve_contact
from lesscli.sim.contact.winkler import phantom_nu

CACHE_VERSION = 1
NODES_ACROSS = 30           # auto mesh: about this many surface nodes across the phantom (at least 2 mm)
MIN_AUTO_MESH_MM = 2.0
STEP_CHUNK = 512            # poses projected at once
DEFAULTS = {"mesh_mm": None, "z_top_mm": 0.7, "z_growth": 1.4, "z_max_mm": 5.0, "nu": None,
            "sensor_skin_mm": 1.5, "sensor_skin_kpa": 400.0, "margin_mm": 0.5, "method": "layered"}
METHODS = ("layered", "splu")


def auto_mesh_mm(phantom) -> float:
    """Default in-plane spacing: ~NODES_ACROSS nodes across the phantom, at least 2 mm."""
    return max(MIN_AUTO_MESH_MM, float(phantom.width_mm) / NODES_ACROSS)


class GreenContact(ContactModel):
    """Tier 2: per-phantom FEM compliance (cached) + unilateral contact QP per step."""

    name = "green"

    def __init__(self, phantom, sensor: dict | None = None, **params) -> None:
        merged = check_params(self.name, params, DEFAULTS)
        if merged["method"] not in METHODS:
            raise SimulationError(f"contact '{self.name}': method must be one of {METHODS}")
        if merged["mesh_mm"] is None:
            merged["mesh_mm"] = auto_mesh_mm(phantom)
        super().__init__(phantom, sensor, **merged)
        self.cache_path = None

    # ----------------------------------------------------------------------------- precompute

    def mesh_params(self) -> dict:
        keys = ("mesh_mm", "z_top_mm", "z_growth", "z_max_mm")
        return {k: float(self.params[k]) for k in keys} | {"nu": phantom_nu(self.phantom, self.params["nu"])}

    def build_mesh(self) -> fem.BodyMesh:
        m = self.mesh_params()
        return fem.phantom_mesh(self.phantom, m["mesh_mm"], m["z_top_mm"], m["z_growth"], m["z_max_mm"])

    def compute_compliance(self) -> dict:
        """Mesh, assemble and reduce: {'c': (m, m) mm/N, 'node_xy': (m, 2) mm, 'asymmetry': ()}."""
        bm = self.build_mesh()
        k = fem.stiffness(self.phantom, bm, self.mesh_params()["nu"])
        if self.params["method"] == "layered":
            c = fem.layered_surface_compliance(k, bm)
        else:
            c = fem.surface_compliance(fem.reduce(k, bm))
        c, asym = fem.symmetrise(c)
        return {"c": c, "node_xy": bm.top_xy_mm, "asymmetry": np.float64(asym)}

    def prepare(self, cache_dir: str | None = None) -> None:
        """Load C from the cache (key: phantom content hash + mesh) or compute and store it."""
        if self._prepared:
            return
        key = cache.cache_key({"v": CACHE_VERSION, "phantom": self.phantom.content_hash(),
                               **self.mesh_params()})
        data = cache.load(self.name, key, cache_dir)
        if data is None:
            data = self.compute_compliance()
            self.cache_path = cache.save(self.name, key, data, cache_dir)
        self.c, self.node_xy = data["c"], data["node_xy"]
        self.asymmetry = float(data["asymmetry"])
        if not np.isfinite(self.c).all():
            raise SimulationError(f"contact '{self.name}': compliance of phantom "
                                  f"'{getattr(self.phantom, 'name', '?')}' is not finite")
        self._setup_steps()
        self._prepared = True

    def _setup_steps(self) -> None:
        h = float(self.params["mesh_mm"])
        skin_kpa = float(self.params["sensor_skin_kpa"])
        self.skin_compliance = (float(self.params["sensor_skin_mm"]) / (skin_kpa * fem.KPA_TO_N_MM2 * h * h)
                                if skin_kpa > 0 else 0.0)
        self._last = None          # (idx, skin, M, cached factors of M's submatrices) of the previous step

    # ----------------------------------------------------------------------------- per step

    def solve_nodes(self, idx: np.ndarray, g: np.ndarray, skin: np.ndarray) -> np.ndarray:
        """Nodal forces (N) on surface nodes ``idx`` with penetration ``g`` (mm) and series compliance
        ``skin``."""
        last = self._last
        if last is not None and np.array_equal(last[0], idx) and np.array_equal(last[1], skin):
            m, factors = last[2], last[3]
        else:
            m = self.c[np.ix_(idx, idx)]
            m[np.diag_indices_from(m)] += skin
            factors = {}
            self._last = (idx, skin, m, factors)
        return solve_contact(m, g, factors=factors)

    def _candidates(self, local_xy: np.ndarray, pen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nodes the pad can touch and their series compliance (mm/N).

        With a sensor skin, a node whose tributary the pad covers only in part (fraction phi) is
        held by a skin patch phi times as large: compliance s / phi. This keeps the force smooth as
        the pad edge sweeps over nodes. Without a skin, nodes whose centre is under the pad count.
        """
        h = float(self.params["mesh_mm"])
        cover = self.pad.coverage(local_xy, h)
        touch = cover > 0 if self.skin_compliance > 0 else cover >= 0.5
        cand = touch & (pen > -float(self.params["margin_mm"]))
        skin = self.skin_compliance / np.where(cand, cover, 1.0)
        return cand, skin

    def _normal(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = pose.shape[0]
        indent = np.zeros(n)
        steps, local, force = [], [], []
        for start in range(0, n, STEP_CHUNK):
            sl = slice(start, min(n, start + STEP_CHUNK))
            proj = kinematics.project_surface(pose[sl], self.node_xy)
            pen = proj.penetration_mm
            under = self.pad.under_pad(proj.local_xy_mm)
            indent[sl] = np.where(under, np.maximum(pen, 0.0), 0.0).max(axis=1, initial=0.0)
            cand, skin = self._candidates(proj.local_xy_mm, pen)
            for j in np.nonzero((cand & (pen > 0)).any(axis=1))[0]:
                idx = np.nonzero(cand[j])[0]
                p = self.solve_nodes(idx, pen[j, idx], skin[j, idx])
                on = p > 0
                steps.append(np.full(int(on.sum()), start + j))
                local.append(proj.local_xy_mm[j, idx[on]])
                force.append(p[on])
        normal = self._bin(pose, steps, local, force)
        c_pen, overhang = self.corner_penetration(pose)
        return normal, np.maximum(indent, c_pen), overhang

    def _bin(self, pose: np.ndarray, steps: list, local: list, force: list) -> np.ndarray:
        """Share nodal vertical forces among taxel cells and project on the pad normal -> (n, T) N."""
        n, t = pose.shape[0], self.pad.taxels
        if not steps:
            return np.zeros((n, t))
        step, xy, p = np.concatenate(steps), np.concatenate(local), np.concatenate(force)
        rot = euler_to_matrix(pose[:, 3:])
        cells, weights = self.pad.share(xy, float(self.params["mesh_mm"]))
        flat = (step[:, None] * t + cells).ravel()
        normal = np.bincount(flat, weights=(weights * p[:, None]).ravel(), minlength=n * t).reshape(n, t)
        return normal * rot[:, 2, 2, None]
