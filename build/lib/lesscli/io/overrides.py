"""Layered settings and the one ``key=value`` syntax of ``--set`` (training configs, scenes, lift configs).

A configuration is a nested table: TOML tables, dicts here, dataclasses in the code. It is resolved in
layers, each over the last: defaults < a TOML file < command-line options < ``--set`` pairs.

A ``--set`` pair is ``key=value``. The key is dotted: ``train.lr`` is ``lr`` in table ``[train]``,
``effects.noise.white_n`` is ``white_n`` in ``[effects.noise]``. The value is a TOML value (``3``,
``1e-4``, ``true``, ``[1, 2]``, ``"a b"``, ``{ low = 1, high = 2 }``); a bare word that is not TOML is
a string (``contact.tier=fem``, ``device=cuda:0``), and so is text TOML would read as a date. A value
that opens a string, array or inline table without closing it is an error, as is an empty one.

Against a dataclass (:func:`resolve_dataclass`) every key must exist, an unknown one is an error that
names the closest known key, and each value must fit its field's type (an integer is accepted for a
float). A document without a fixed schema (a scene) takes its pairs as they come
(:func:`apply_overrides`) and is checked by its own validation.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping

from lesscli.errors import DataError, did_you_mean

Path = tuple[str, ...]
_OPENERS = ('"', "'", "[", "{")          # a value starting so is TOML or an error, never a bare string
_DATES = (datetime.date, datetime.time)  # TOML reads 2024-01-01 as a date; settings take it as text


def parse_value(text: str, where: str = "--set") -> object:
    """A ``--set`` value: TOML syntax, else the text itself (see the module docstring).

    Raises:
        DataError: an empty value, a line break, or an unclosed string, array or inline table.
    """
    text = text.strip()
    if not text or "\n" in text:
        raise DataError(f"{where}: {'an empty value' if not text else 'a line break in the value'}; "
                        "give a TOML value, e.g. 3, 1e-4, true, [1, 2] or \"text\"")
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError as exc:
        if text.startswith(_OPENERS):
            reason = str(exc).split(" (at ")[0]
            raise DataError(f"{where}: malformed value '{text}' ({reason})") from None
        return text
    return text if isinstance(value, _DATES) else value


def parse_assignment(item: str, where: str = "") -> tuple[Path, object]:
    """``'a.b=value'`` -> (``('a', 'b')``, parsed value); DataError when it is not ``key=value``."""
    source = _source(item, where)
    key, eq, text = item.partition("=")
    keys = tuple(part.strip() for part in key.split("."))
    if not eq or not all(keys):
        raise DataError(f"{source} is not of the form key=value (e.g. train.lr=3e-4 or motion.n_traj=10)")
    return keys, parse_value(text, source)


def set_path(doc: dict, keys: Path, value, source: str) -> None:
    """Set ``doc[k0][k1]...`` to ``value`` in place, creating missing tables."""
    node = doc
    for depth, key in enumerate(keys[:-1]):
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise DataError(f"{source}: '{'.'.join(keys[:depth + 1])}' is a value, not a table")
    node[keys[-1]] = value


def apply_overrides(doc: dict, overrides: Iterable[str], where: str = "",
                    options: Mapping[str, object] | None = None) -> dict:
    """A copy of ``doc`` with ``options`` (dotted key -> value; None = not given), then the ``--set``
    ``overrides``, applied; ``doc`` itself is not modified."""
    out = copy.deepcopy(doc)
    for key, value in (options or {}).items():
        if value is not None:
            set_path(out, tuple(key.split(".")), value, where or "option")
    for item in overrides:
        keys, value = parse_assignment(item, where)
        set_path(out, keys, value, _source(item, where))
    return out


def check_known(doc: dict, known: Mapping, where: str, path: Path = ()) -> None:
    """Raise DataError for the first key of ``doc`` not in the tree ``known`` (nested mappings; a leaf is
    anything else), naming the closest known key. A table where a value belongs, or the reverse, is an
    error too."""
    for key, value in doc.items():
        if key not in known:
            _unknown(where, path, key, known)
        if isinstance(known[key], Mapping):
            if not isinstance(value, dict):
                raise DataError(f"{where}: [{'.'.join((*path, key))}] must be a table of settings")
            check_known(value, known[key], where, (*path, key))
        elif isinstance(value, dict):
            raise DataError(f"{where}: {_name(path, key)} is a setting, not a table")


def resolve_dataclass(cls, doc: dict | None = None, where: str = "config",
                      options: Mapping[str, object] | None = None, overrides: Iterable[str] = (),
                      short_keys: bool = False):
    """``cls()`` defaults < ``doc`` (tables as in its TOML file, from ``where``) < ``options`` (dotted field
    paths -> values, None = not given) < ``overrides`` (``--set`` pairs), as a new ``cls``.

    Nested dataclass fields are tables. With ``short_keys``, a ``--set`` key may be a bare field name
    found in exactly one table (``lr`` for ``train.lr``).

    Raises:
        DataError: an unknown or ambiguous key (naming the closest), a value of the wrong type, a pair
            that is not ``key=value``.
    """
    tree = dataclasses.asdict(cls())
    kinds = _kinds(cls)
    if doc:
        check_known(doc, kinds, where)
        for keys, value in _leaves(doc):
            _assign(tree, kinds, keys, value, where)
    for key, value in (options or {}).items():
        if value is not None:
            _assign(tree, kinds, _locate(kinds, tuple(key.split(".")), "option", False), value, "option")
    for item in overrides:
        keys, value = parse_assignment(item)
        _assign(tree, kinds, _locate(kinds, keys, _source(item), short_keys), value, _source(item))
    return _build(cls, tree)


def coerce(value, kind, what: str):
    """``value`` as type ``kind`` (int, float, str, bool, a union of them, or list); an int is taken for a
    float, a bool never for a number. DataError naming ``what`` otherwise."""
    options = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    for option in options:
        if (option is type(None) and value is None) or (option is bool and isinstance(value, bool)) or \
                (option is str and isinstance(value, str)) or \
                (option is int and number and isinstance(value, int)):
            return value
        if option is float and number:
            return float(value)
        if (typing.get_origin(option) is list or option is list) and isinstance(value, list):
            return value
    need = "/".join(getattr(o, "__name__", str(o)) for o in options)
    if not number and any(o in (int, float) for o in options) and not isinstance(value, bool):
        raise DataError(f"{what} must be a number (expects {need}), got {value!r}")
    raise DataError(f"{what} expects {need}, got {value!r}")


def _source(item: str, where: str = "") -> str:
    """How an error names a ``--set`` pair (after the file it applies to, if any)."""
    return f"{where}: --set '{item}'" if where else f"--set '{item}'"


def _kinds(cls) -> dict:
    """The tree of ``cls``'s fields: a nested dict per dataclass field, the type hint for the others."""
    hints = typing.get_type_hints(cls)
    return {f.name: _kinds(hints[f.name]) if dataclasses.is_dataclass(hints[f.name]) else hints[f.name]
            for f in dataclasses.fields(cls)}


def _build(cls, tree: dict):
    hints = typing.get_type_hints(cls)
    return cls(**{name: _build(hints[name], value) if dataclasses.is_dataclass(hints[name]) else value
                  for name, value in tree.items()})


def _leaves(doc: dict, path: Path = ()):
    for key, value in doc.items():
        if isinstance(value, dict):
            yield from _leaves(value, (*path, key))
        else:
            yield (*path, key), value


def _name(path: Path, key: str) -> str:
    return f"[{'.'.join(path)}] '{key}'" if path else f"'{key}'"


def _unknown(where: str, path: Path, key: str, known: Mapping) -> None:
    tables = [k for k, v in known.items() if isinstance(v, Mapping)]
    what = "table" if tables and len(tables) == len(known) else "key"
    label = f"[{'.'.join(path)}] unknown {what} '{key}'" if path else f"unknown {what} '{key}'"
    raise DataError(f"{where}: {label}" + did_you_mean(key, known, f" (known: {', '.join(sorted(known))})"))


def _locate(kinds: dict, keys: Path, where: str, short_keys: bool) -> Path:
    """The full path of a (possibly bare) key; DataError naming the closest known key when there is none."""
    if short_keys and len(keys) == 1 and keys[0] not in kinds:
        owners = [(*path, keys[0]) for path, table in _tables(kinds) if keys[0] in table
                  and not isinstance(table[keys[0]], Mapping)]
        if len(owners) == 1:
            return owners[0]
        if owners:
            raise DataError(f"{where}: '{keys[0]}' is ambiguous; use one of "
                            + ", ".join(".".join(o) for o in owners))
        names = {name for _, table in _tables(kinds) for name in table}
        raise DataError(f"{where}: unknown key '{keys[0]}'" + did_you_mean(keys[0], names))
    node = kinds
    for depth, key in enumerate(keys):
        if not isinstance(node, Mapping):
            raise DataError(f"{where}: '{'.'.join(keys[:depth])}' is a setting, not a table")
        if key not in node:
            _unknown(where, keys[:depth], key, node)
        node = node[key]
    if isinstance(node, Mapping):
        raise DataError(f"{where}: [{'.'.join(keys)}] is a table; set one of its keys, e.g. "
                        f"{'.'.join(keys)}.{next(iter(node))}=...")
    return keys


def _tables(kinds: Mapping, path: Path = ()):
    yield path, kinds
    for key, value in kinds.items():
        if isinstance(value, Mapping):
            yield from _tables(value, (*path, key))


def _assign(tree: dict, kinds: dict, keys: Path, value, where: str) -> None:
    kind = kinds
    for key in keys:
        kind = kind[key]
    node = tree
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = coerce(value, kind, f"{where}: '{'.'.join(keys)}'")
