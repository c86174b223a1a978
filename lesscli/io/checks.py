"""Array and metadata checks shared by every file reader (scan sets, predictions, label volumes).

Each check raises DataError with one line naming the file, the key and what is wrong, so a rule is
written once and every reader words it the same way. ``name`` is the file as the user typed it
(``<stdin>`` for ``-``).
"""

from __future__ import annotations

import json

import numpy as np

from lesscli.errors import DataError

NUMBER_KINDS = "biuf"  # numpy dtype kinds that hold plain numbers (bool, int, uint, float)
JSON_KINDS = {list: "array", str: "string", int: "number", float: "number", bool: "boolean",
              type(None): "null"}


def require(arrays: dict, key: str, name: str, what: str) -> np.ndarray:
    """``arrays[key]`` or DataError saying the key is missing from a ``what`` file."""
    if key not in arrays:
        raise DataError(f"{name}: missing key '{key}' (not a {what} file?)")
    return arrays[key]


def numbers(arr, key: str, name: str, integer: bool = False, dtype=np.float64) -> np.ndarray:
    """``arr`` as ``dtype`` (float64; int64 with ``integer``) if it holds plain numbers, else DataError.

    Strings, bytes, complex numbers and (for ``integer``) fractional values are refused. An array
    already of ``dtype`` is returned as it is (no copy); values beyond a narrower float's range
    become inf (for :func:`finite` to name).
    """
    arr = np.asarray(arr)
    if arr.dtype.kind not in NUMBER_KINDS:
        raise DataError(f"{name}: '{key}' holds {arr.dtype} values, expected numbers")
    if not integer:
        with np.errstate(over="ignore"):
            return arr.astype(dtype, copy=False)
    if arr.dtype.kind == "f" and not (np.isfinite(arr).all() and (arr == np.round(arr)).all()):
        raise DataError(f"{name}: '{key}' must hold whole numbers")
    return arr.astype(np.int64)


def shape(arr: np.ndarray, key: str, name: str, expected: tuple, text: str) -> None:
    """Check ``arr.shape`` against ``expected``, where None matches any length."""
    ok = arr.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, arr.shape))
    if not ok:
        raise DataError(f"{name}: '{key}' has shape {arr.shape}, expected {text}")


FINITE_BLOCK = 1 << 20      # values checked at a time by ``finite`` (bounds its temporary memory)


def finite(arr: np.ndarray, key: str, name: str, unit: str = "step", dtype=None) -> None:
    """Every value finite (also once cast to ``dtype``, e.g. float32); names the first bad ``unit``.

    Checked a block of rows at a time, so a large array costs no full-size copy or mask."""
    beyond = "" if dtype is None else f"; values beyond {np.dtype(dtype).name} range count as inf"
    flat = np.asarray(arr)
    flat = flat.reshape(len(flat), int(np.prod(flat.shape[1:]))) if flat.ndim else flat.reshape(1, 1)
    rows = max(1, FINITE_BLOCK // max(1, flat.shape[1]))
    bad = np.zeros(len(flat), bool)
    for start in range(0, len(flat), rows):
        block = flat[start:start + rows]
        if dtype is not None:
            with np.errstate(over="ignore"):
                block = block.astype(dtype, copy=False)
        bad[start:start + rows] = ~np.isfinite(block).all(axis=1)
    if bad.any():
        raise DataError(f"{name}: '{key}' has NaN or inf at {unit} {int(np.flatnonzero(bad)[0])} "
                        f"({int(bad.sum())} {unit}s affected{beyond})")


def positive(arr: np.ndarray, key: str, name: str, unit: str) -> None:
    """Every value finite and > 0 (e.g. voxel spacing); names the first bad ``unit``."""
    finite(arr, key, name, unit)
    bad = (~(arr.reshape(len(arr), int(np.prod(arr.shape[1:]))) > 0).all(axis=1) if arr.ndim
           else np.array([not arr > 0]))
    if bad.any():
        raise DataError(f"{name}: '{key}' must be positive, {unit} {int(np.flatnonzero(bad)[0])} is not")


def in_range(arr: np.ndarray, key: str, name: str, low: int, high: int, meaning: str = "") -> None:
    """Integer codes within ``low..high`` (inclusive)."""
    if arr.size and (int(arr.min()) < low or int(arr.max()) > high):
        found = int(arr.min()) if int(arr.min()) < low else int(arr.max())
        raise DataError(f"{name}: '{key}' must be {low}..{high}{meaning}, found {found}")


def json_object(arrays: dict, key: str, name: str, what: str) -> dict:
    """Parse the JSON object stored as a string scalar under ``key``."""
    raw = require(arrays, key, name, what)
    if raw.ndim != 0 or raw.dtype.kind not in "US":
        raise DataError(f"{name}: '{key}' must be one JSON string, got a {raw.dtype} array of shape "
                        f"{raw.shape}")
    try:
        value = json.loads(str(raw[()]))
    except (json.JSONDecodeError, ValueError):
        raise DataError(f"{name}: '{key}' is not valid JSON") from None
    if not isinstance(value, dict):
        kind = JSON_KINDS.get(type(value), type(value).__name__)
        raise DataError(f"{name}: '{key}' is a JSON {kind}, expected an object {{...}}")
    return value


def declared_schema(arrays: dict) -> str | None:
    """The schema a file's ``meta`` names (``less.scans``, ``less.pred``), read leniently to tell a file's
    kind: None where there is no ``meta``, or it is not a JSON object (the file's own reader says why)."""
    if "meta" not in arrays:
        return None
    try:
        schema = json.loads(str(arrays["meta"])).get("schema")
    except (ValueError, AttributeError):
        return None
    return schema if isinstance(schema, str) else None


def schema_meta(arrays: dict, name: str, schema: str, version: int, what: str) -> dict:
    """The ``meta`` object of a ``schema/version`` file, with its schema, version and history checked."""
    meta = json_object(arrays, "meta", name, f"{schema}/{version} {what}")
    if meta.get("schema") != schema:
        raise DataError(f"{name}: not a {schema}/{version} {what} (meta schema is {meta.get('schema')!r})")
    if meta.get("version") != version:
        raise DataError(f"{name}: unsupported {schema} version {meta.get('version')!r} "
                        f"(this toolkit reads version {version})")
    if not isinstance(meta.get("history", []), list):
        raise DataError(f"{name}: meta 'history' must be a list")
    return meta


def meta_field(meta: dict, key: str, name: str, kinds: tuple, text: str, prefix: str = ""):
    """``meta[key]`` if absent (None) or of one of ``kinds`` (bool is never a number), else DataError.

    ``prefix`` names the enclosing object in the message (``sensor.`` for ``meta.sensor.taxels``).
    """
    value = meta.get(key)
    if value is None:
        return None
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        raise DataError(f"{name}: meta '{prefix}{key}' must be {text}, got {json.dumps(value)[:40]}")
    return value


def text_array(arr, key: str, name: str, what: str) -> np.ndarray:
    """``arr`` as a str array if it holds text (names), else DataError."""
    arr = np.asarray(arr)
    if arr.dtype.kind not in "US":
        raise DataError(f"{name}: '{key}' holds {arr.dtype} values, expected {what} (text)")
    return arr.astype(str)
