"""TOML inputs (scene files, training configs, lift configs, phantom sets): one reader, one wording; and
the writer of resolved settings (``--print-config``)."""

from __future__ import annotations

import json
import numbers
import os
import re
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


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def dump_toml(doc: dict) -> str:
    """``doc`` as TOML text (``tomllib.loads`` gives it back): values first, then one ``[table]`` per nested
    dict; None values are left out (TOML has no null: the key keeps its default)."""
    lines: list[str] = []
    _dump_table(doc, (), lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _dump_table(table: dict, path: tuple[str, ...], lines: list[str]) -> None:
    values = {k: v for k, v in table.items() if v is not None and not isinstance(v, dict)}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if path and (values or not tables):
        lines += ["", f"[{'.'.join(_toml_key(k) for k in path)}]"]
    lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in values.items()]
    for key, sub in tables.items():
        _dump_table(sub, (*path, key), lines)


def _toml_key(key) -> str:
    key = str(key)
    return key if _BARE_KEY.fullmatch(key) else _toml_string(key)


def _toml_string(text: str) -> str:
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")   # JSON escapes are TOML escapes


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))                    # repr: shortest exact form; inf, -inf and nan as TOML
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()
                                if v is not None) + " }"
    raise TypeError(f"no TOML form for {type(value).__name__} {value!r}")
