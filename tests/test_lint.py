"""The tree passes ruff's pycodestyle and pyflakes rules (`[tool.ruff.lint]` in pyproject.toml):
unused imports and names, undefined names, lines over 100 characters, ambiguous lambdas."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_tree_passes_ruff() -> None:
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."],
                         cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
