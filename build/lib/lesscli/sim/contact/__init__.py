"""Contact tiers (the accuracy-vs-time ladder of SIMULATION.md).

``CONTACT_TIERS[name](phantom, sensor, **params)`` builds a model; ``model.prepare(cache_dir)``
does the per-phantom precompute; ``model.solve(pose)`` maps (n, 6) pad poses to a ContactResult;
``model.depth_for_force(x, y, yaw, target_n)`` inverts the total normal force.

- ``winkler`` (tier 0): column springs + blur + one gain.
- ``green`` (tier 2, default): FEM surface compliance + unilateral contact QP per step.
- ``fem`` (tier 3): direct FEM with active-set contact, for validation.
"""

from lesscli.sim.contact.base import (
    FLAG_LARGE_STRAIN,
    FLAG_OUTSIDE_VALIDITY,
    FLAG_PAD_OVERHANG,
    ContactModel,
    ContactResult,
    PadGeometry,
)
from lesscli.sim.contact.direct import FemContact
from lesscli.sim.contact.green import GreenContact
from lesscli.sim.contact.winkler import WinklerContact

CONTACT_TIERS: dict[str, type] = {"winkler": WinklerContact, "green": GreenContact, "fem": FemContact}
DEFAULT_TIER = "green"

__all__ = ["CONTACT_TIERS", "DEFAULT_TIER", "FLAG_LARGE_STRAIN", "FLAG_OUTSIDE_VALIDITY", "FLAG_PAD_OVERHANG",
           "ContactModel", "ContactResult", "FemContact", "GreenContact", "PadGeometry",
           "WinklerContact"]
