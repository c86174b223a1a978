"""docs/: the reference pages are what tools/gen_reference.py writes from today's CLI, every subcommand and
results page is reachable, and the MkDocs site builds with no broken link (where MkDocs is installed)."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "tools" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_reference_pages_equal_the_clis_help():
    # a fresh process: click caches a command's help option (and its names) the first time it is built
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_reference.py"), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300, check=False,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr


def test_every_leaf_subcommand_has_a_section():
    import click

    from lesscli.cli.main import cli

    pages = _generator().pages()
    ctx = click.Context(cli, info_name="less")
    for name in cli.list_commands(ctx):
        command = cli.get_command(ctx, name)
        page = pages[f"{name}.md"]
        assert f"Usage: less {name} " in page
        if isinstance(command, click.Group):
            sub = click.Context(command, info_name=name, parent=ctx)
            for leaf in command.list_commands(sub):
                assert f"## less {name} {leaf}\n" in page and f"Usage: less {name} {leaf} " in page


def test_every_page_is_in_the_nav_or_the_results_index():
    nav = (ROOT / "mkdocs.yml").read_text()
    for page in sorted((DOCS / "guide").glob("*.md")) + sorted((DOCS / "reference").glob("*.md")):
        assert str(page.relative_to(DOCS)) in nav, f"{page.relative_to(ROOT)} is not in mkdocs.yml's nav"
    index = (DOCS / "results" / "index.md").read_text()
    for page in sorted((DOCS / "results").glob("*.md")):
        if page.name == "index.md":
            continue
        assert f"]({page.name})" in index, f"{page.relative_to(ROOT)} has no row in docs/results/index.md"
        head = page.read_text().split("\n\n", 2)[1]
        for field in ("**Measures:**", "**Command:**", "**Commit:**"):
            assert field in head, f"{page.relative_to(ROOT)}: no {field} line under its title"
        commit = re.search(r"\*\*Commit:\*\* ([0-9a-f]{7,40})", head).group(1)
        found = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{commit}^{{commit}}"],
                               capture_output=True, check=False)
        assert found.returncode == 0, f"{page.name}: no commit {commit}"


def test_every_results_folder_names_its_command():
    folders = [d for d in (ROOT / "examples" / "results").iterdir() if d.is_dir()]
    assert folders
    for folder in folders:
        readme = folder / "README.md"
        assert readme.exists(), f"{folder.relative_to(ROOT)} has no README naming the command that made it"
        assert re.search(r"```sh\n.*\b(make|less|python)\b", readme.read_text(), flags=re.DOTALL), readme


def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="MkDocs is not installed (pip install '.[docs]')")
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    assert mkdocs, "the mkdocs module is installed but not its command"
    proc = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "reference" / "simulate" / "index.html").exists()
