"""Low-level geometry with numpy only (no files, no torch): importable from every other folder."""
