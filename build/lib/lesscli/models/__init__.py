"""Models: particle encoder (LESS), GLOBAL baseline, positional encoding, decoders, losses."""
