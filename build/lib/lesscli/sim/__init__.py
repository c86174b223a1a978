"""Palpation simulator: kinematics, contact tiers, motions, effects and scenes."""
