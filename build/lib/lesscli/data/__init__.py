"""Dataset operations (subsample, concat, split, import) and torch datasets."""
