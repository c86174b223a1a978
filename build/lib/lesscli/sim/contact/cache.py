"""On-disk cache of per-phantom precomputes, keyed by content hash.

Directory: the ``cache_dir`` argument, else ``$LESS_CACHE_DIR``, else ``~/.cache/less/contact`` (the
same default as the scene's ``contact.cache_dir``). Entries are
``<tier>-<key>.npz`` (no pickle), written atomically, so concurrent workers at worst compute twice.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from lesscli.io.atomic import atomic_path

ENV_VAR = "LESS_CACHE_DIR"


def cache_root(cache_dir: str | None = None) -> Path:
    """The cache directory (not created)."""
    if cache_dir:
        return Path(cache_dir)
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path.home() / ".cache" / "less" / "contact"


def cache_key(parts: dict) -> str:
    """SHA-1 of a JSON-able dict (sorted keys)."""
    return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def load(tier: str, key: str, cache_dir: str | None = None) -> dict | None:
    """The cached arrays, or None when absent or unreadable."""
    path = cache_root(cache_dir) / f"{tier}-{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except (OSError, ValueError):
        return None


def save(tier: str, key: str, arrays: dict, cache_dir: str | None = None) -> Path | None:
    """Write arrays atomically; returns the path, or None if the directory is not writable."""
    root = cache_root(cache_dir)
    path = root / f"{tier}-{key}.npz"
    try:
        root.mkdir(parents=True, exist_ok=True)
        with atomic_path(str(path), ".npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    except OSError:
        return None
    return path
