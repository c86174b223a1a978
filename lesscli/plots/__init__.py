"""Figures: truth | prediction | uncertainty panels and time strips (matplotlib, Agg chosen inside
functions)."""
