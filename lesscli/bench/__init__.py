"""Benchmarks that need several layers at once (simulation, training, inference, metrics)."""
