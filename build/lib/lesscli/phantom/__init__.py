"""Phantom geometry: octagonal inserts with skin, filling, spherical inclusions and pillars."""

from lesscli.phantom.geometry import Material, Phantom, Pillar, Sphere

__all__ = ["Material", "Phantom", "Pillar", "Sphere"]
