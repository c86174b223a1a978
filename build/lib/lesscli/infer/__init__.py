"""Inference: batch prediction of label images from scan sets."""
