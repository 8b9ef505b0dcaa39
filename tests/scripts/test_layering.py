"""The packages import one way only (../shared/DESIGN.md sec. 1): ``earth`` <- ``nav_filters`` <- ``envs`` <-
``experiments`` <- ``agents`` <- the scripts. Read from the source (every ``import`` / ``from ... import``
statement, at any depth, including those inside functions), not by importing anything."""
import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ORDER = ("earth", "nav_filters", "envs", "experiments", "agents")
"""Lowest first: a package may import only the packages before it (and itself)."""


def imported_packages(path: Path) -> set[tuple[str, int]]:
    """``(top-level package, line)`` of every absolute import in ``path`` that names one of :data:`ORDER`."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        out |= {(n.split(".")[0], node.lineno) for n in names if n.split(".")[0] in ORDER}
    return out


def violations(package: str) -> list[str]:
    """``file:line imports X`` for every import of a package above ``package`` in :data:`ORDER`."""
    above = set(ORDER[ORDER.index(package) + 1:])
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for top, line in sorted(imported_packages(path)):
            if top in above:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {top}")
    return bad


@pytest.mark.parametrize("package", ORDER)
def test_package_imports_only_lower_layers(package):
    assert (ROOT / package / "__init__.py").is_file()
    assert violations(package) == []


def test_the_scan_sees_an_upward_import(tmp_path, monkeypatch):
    """The checker itself: a file of ``envs`` that imports ``agents`` inside a function is reported."""
    pkg = tmp_path / "envs"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "bad.py").write_text("import numpy\n\ndef f():\n    from agents.methods import x\n    return x\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert violations("envs") == ["envs/bad.py:4 imports agents"]
    assert violations("agents") == []
