"""The tree passes ruff's pycodestyle and pyflakes rules (`[tool.ruff.lint]` in pyproject.toml):
unused imports and names, undefined names, lines over 100 characters, ambiguous lambdas; and
the scripts stay thin."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_tree_passes_ruff() -> None:
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."],
                         cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_scripts_hold_only_short_functions() -> None:
    """A script is a thin command over the package: no function in scripts/ over 30 lines
    (docstring included), so that analysis worth more lands in a tested module."""
    import ast

    long = []
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > 30:
                    long.append(f"{path.name}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, long
