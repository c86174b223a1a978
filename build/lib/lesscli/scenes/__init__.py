"""Scene files shipped with the package, so that a wheel alone can simulate (``less simulate quick``).

``examples/scenes/*.toml`` are links to these files; ``examples/scenes/dev-multiple.json`` (a phantom
set written by ``examples/dev_multiple.py``) stays with the examples.
"""

from __future__ import annotations

import os

from lesscli.errors import DataError

HERE = os.path.dirname(os.path.abspath(__file__))


def names() -> list[str]:
    """The packaged scenes' names (file names without ``.toml``), sorted."""
    return sorted(f[:-5] for f in os.listdir(HERE) if f.endswith(".toml"))


def resolve(path: str) -> str:
    """``path`` itself where it exists (or is ``-``), else the packaged scene of that name (``quick`` or
    ``quick.toml``); a path with a folder in it is returned as it is, for its reader to name."""
    if path == "-" or os.path.exists(path) or os.sep in path:
        return path
    name = path.removesuffix(".toml")
    packaged = os.path.join(HERE, f"{name}.toml")
    if os.path.isfile(packaged):
        return packaged
    raise DataError(f"{path}: no such scene file, nor a packaged scene (those are: {', '.join(names())})")
