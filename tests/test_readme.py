"""The README: its length, its links, and its tutorial, run as written from an empty folder.

Blocks marked ``<!-- runnable -->`` run in order in one shell; the table after ``<!-- tutorial-result -->``
is what one run printed, and the run here must print the same to within a tolerance (training sums
in another order on another number of threads).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
BIN = Path(sys.executable).parent
F1_TOLERANCE = 0.1
LINK = re.compile(r"\]\(([^)#\s]+)(?:#([^)\s]+))?\)")


def runnable_blocks(text: str) -> list[str]:
    """The shell blocks that follow a ``<!-- runnable -->`` line, in order."""
    return re.findall(r"<!-- runnable -->\n```sh\n(.*?)```", text, flags=re.DOTALL)


def markdown_rows(text: str) -> dict[str, list[str]]:
    """model -> cells of a markdown table's body rows (the header and the rule left out)."""
    rows = {}
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    for line in lines[2:]:
        cells = dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True))
        rows[cells["model"]] = cells
    return rows


def slug(heading: str) -> str:
    """The anchor GitHub and MkDocs give a heading (lower case, punctuation dropped, spaces -> -)."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("path", ["README.md", "examples/README.md"])
def test_at_most_400_lines(path):
    assert len((ROOT / path).read_text().splitlines()) <= 400


@pytest.mark.parametrize("readme", ["README.md", "examples/README.md"])
def test_links_reach_files_and_headings(readme):
    links = LINK.findall((ROOT / readme).read_text())
    assert len(links) > 15
    for target, anchor in links:
        if target.startswith("http"):
            continue
        path = (ROOT / readme).parent / target
        assert path.exists(), f"{readme} links to {target}, which does not exist"
        if anchor:
            headings = {slug(h) for h in re.findall(r"^#+ (.*)$", path.read_text(), flags=re.MULTILINE)}
            assert anchor in headings, f"{readme} links to {target}#{anchor}: no such heading"


def test_every_subcommand_is_in_the_commands_table():
    from lesscli.cli.registry import COMMANDS

    text = README.read_text()
    for name in COMMANDS:
        assert f"[`less {name}" in text, f"less {name} is missing from the README's commands table"


def test_runnable_blocks_are_the_tutorial():
    blocks = runnable_blocks(README.read_text())
    assert len(blocks) == 3
    assert blocks[0].startswith("less simulate quick") and "tee metrics.md" in blocks[2]


@pytest.mark.slow
def test_tutorial_runs_from_an_empty_folder_and_prints_its_table(tmp_path):
    text = README.read_text()
    script = "set -euo pipefail\n" + "\n".join(runnable_blocks(text))
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=1500, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = markdown_rows((tmp_path / "metrics.md").read_text())
    stated = markdown_rows(text.split("<!-- tutorial-result -->", 1)[1].split("\n\n", 1)[0])
    assert set(got) == set(stated) == {"less-taxel", "forcemap", "average"}
    for model, row in stated.items():
        assert got[model]["n"] == row["n"]
        if row["f1_micro_3d"] != "-":
            f1 = float(got[model]["f1_micro_3d"])
            assert abs(f1 - float(row["f1_micro_3d"])) <= F1_TOLERANCE, (model, f1, row)
    # it learns: a model that finds nothing scores 0
    assert float(got["less-taxel"]["f1_micro_3d"]) >= 0.5
    assert len(list((tmp_path / "figures").glob("*.png"))) == 6
