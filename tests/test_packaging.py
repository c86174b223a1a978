"""Packaging: the distribution's name and dependencies, torch's range, the scenes shipped in the wheel.

The full check (a wheel installed into a fresh venv runs ``less --help`` and ``less simulate quick``)
is ``make wheel-check`` (tools/check_wheel.sh): it needs a package index, so it is not part of the suite.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PROJECT = PYPROJECT["project"]

# import name -> the distribution that provides it
PROVIDERS = {"cv2": "opencv-contrib-python-headless", "serial": "pyserial", "skimage": "scikit-image",
             "skfem": "scikit-fem", "dynamixel_sdk": "dynamixel-sdk", "pydicom": "pydicom"}
OPTIONAL = {"pydicom": "dicom", "tensorboard": "tensorboard"}


def _requirement_names(requirements: list[str]) -> set[str]:
    return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower() for r in requirements}


def _third_party_imports() -> set[str]:
    """Top-level modules that lesscli imports and the standard library does not hold."""
    found = set()
    for path in (ROOT / "lesscli").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return {m for m in found if m not in sys.stdlib_module_names and m not in ("lesscli", "__future__")}


def test_distribution_name_and_commands():
    assert PROJECT["name"] == "less-tactile"
    assert PROJECT["scripts"] == {"less": "lesscli.cli.main:entry", "lesscli": "lesscli.cli.main:entry"}


def test_every_imported_package_is_declared():
    runtime = _requirement_names(PROJECT["dependencies"])
    for module in sorted(_third_party_imports()):
        dist = PROVIDERS.get(module, module).lower()
        if module in OPTIONAL:
            extra = PROJECT["optional-dependencies"][OPTIONAL[module]]
            assert dist in _requirement_names(extra), f"{module}: not in the '{OPTIONAL[module]}' extra"
        else:
            assert dist in runtime, f"lesscli imports {module}, but {dist} is not a dependency"
    assert "threadpoolctl" in runtime and "opencv-python-headless" not in runtime


def test_torch_range_is_the_makefiles():
    (torch,) = [r for r in PROJECT["dependencies"] if r.startswith("torch")]
    (line,) = [ln for ln in (ROOT / "Makefile").read_text().splitlines() if ln.startswith("TORCH ")]
    assert line.split(":=", 1)[1].strip() == torch


def test_example_scenes_are_the_packaged_ones():
    from lesscli.scenes import HERE, names, resolve

    assert {"quick", "poke", "primitive", "handheld"} <= set(names())
    for name in names():
        example = ROOT / "examples" / "scenes" / f"{name}.toml"
        assert example.resolve() == (Path(HERE) / f"{name}.toml").resolve(), example
        assert resolve(name) == resolve(f"{name}.toml") == os.path.join(HERE, f"{name}.toml")
    assert resolve(str(example)) == str(example)                  # an existing path is read as it is
    assert PYPROJECT["tool"]["setuptools"]["package-data"]["lesscli.scenes"] == ["*.toml"]


@pytest.mark.slow
def test_wheel_holds_the_package_scenes_and_commands(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(tmp_path), str(ROOT)], check=True, capture_output=True)
    (wheel,) = tmp_path.glob("less_tactile-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        meta = next(n for n in names if n.endswith(".dist-info/METADATA"))
        metadata = zf.read(meta).decode()
        entry_points = zf.read(meta.replace("METADATA", "entry_points.txt")).decode()
    assert {"lesscli/scenes/quick.toml", "lesscli/scenes/poke.toml", "lesscli/cli/main.py"} <= names
    assert "Name: less-tactile" in metadata and "Requires-Dist: threadpoolctl" in metadata
    assert ("less = lesscli.cli.main:entry" in entry_points
            and "lesscli = lesscli.cli.main:entry" in entry_points)
    assert not any(n.startswith(("tests/", "examples/")) for n in names)
