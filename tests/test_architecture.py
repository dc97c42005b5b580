"""The dependency rules of README's "Layout and data flow", enforced on the source with ast."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "tamedpuma"


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            base = ".".join(path.relative_to(PKG.parent).with_suffix("").parts[:-node.level])
            names.add(f"{base}.{node.module}" if node.module else base)
    return names


def _modules():
    return sorted(p for p in PKG.rglob("*.py"))


def _top(names):
    return {n.split(".")[0] for n in names}


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_import_rules(path):
    rel = path.relative_to(PKG)
    names = _imports(path)
    top = _top(names)
    if "pybullet" in top:
        assert rel.as_posix() == "worlds/bullet.py", "only the simulator imports PyBullet"
    if "hydra" in top:
        assert rel.parts[0] == "app", "only entry points (app/) import Hydra"
    if "torch" in top:
        assert rel.parts[0] in ("puma", "app"), "torch only in the learner and entry points"
    if rel.parts[0] == "methods":
        assert "tamedpuma.worlds.bullet" not in names, "methods never import the simulator"
    if rel.parts[0] == "fabrics" or rel.as_posix() in (
            "types.py", "robot/rotations.py", "metrics.py", "methods/_modulation.py",
            "methods/_policy.py"):
        assert top <= {"numpy", "tamedpuma", "__future__", "collections", "dataclasses",
                       "typing", "math", "warnings"}, f"{rel} must stay numpy-only: {top}"
