"""TOML inputs (scene files, training configs, lift configs, phantom sets): one reader, one wording."""

from __future__ import annotations

import os
import tomllib

from lesscli.errors import DataError


def read_toml(path: str, what: str) -> dict:
    """The document at ``path``; a missing, unreadable, non-UTF-8 or malformed file raises one DataError
    naming the file (``what`` says what it should be, e.g. "scene file")."""
    if not os.path.exists(path):
        raise DataError(f"{path}: no such {what}")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise DataError(f"{path}: cannot read {what}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not valid TOML ({exc})") from None
