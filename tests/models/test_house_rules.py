"""The design's rules for ``lesscli/models/`` (DESIGN.md, section 2): it imports torch and its own modules
only (never ``io``, ``data`` or the file system: checkpoints are opened by ``train/`` and ``infer/``), and
its modules import each other without a cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import lesscli.models

MODELS = Path(lesscli.models.__file__).parent
ALLOWED = ("lesscli.models", "lesscli.types", "lesscli.errors")
FILE_CALLS = {"open", "load", "save"}                 # open(...), torch.load / torch.save, np.load ...


def _imports(path: Path) -> list[str]:
    """Every lesscli module ``path`` imports, at the top or inside a function."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("lesscli"):
            found.append(node.module)
        elif isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.startswith("lesscli")]
    return found


def test_models_import_only_torch_and_their_own_modules():
    wrong = {p.name: m for p in MODELS.glob("*.py") for m in _imports(p) if not m.startswith(ALLOWED)}
    assert wrong == {}


def test_models_touch_no_files():
    calls = []
    for path in MODELS.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                name = (node.func.attr if isinstance(node.func, ast.Attribute)
                        else getattr(node.func, "id", ""))
                if name in FILE_CALLS:
                    calls.append((path.name, node.lineno, name))
    assert calls == []


def test_model_modules_import_each_other_without_a_cycle():
    graph = {p.stem: {m.rsplit(".", 1)[1] for m in _imports(p) if m.startswith("lesscli.models.")}
             for p in MODELS.glob("*.py")}
    state: dict[str, str] = {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            assert state.get(nxt) != "open", f"import cycle: {' -> '.join([*path, node, nxt])}"
            if nxt not in state:
                visit(nxt, [*path, node])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [])
