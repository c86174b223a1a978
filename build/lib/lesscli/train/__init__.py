"""Training: SSL pretraining, the generic loop, checkpoints, distributed setup."""
