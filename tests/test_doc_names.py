"""Every `module.symbol` the pages name in backticks exists: a dotted name whose first part is
springc, one of its packages or one of its modules by its own name (`check.store`,
`springc.design.summer.design_summer`, `codegen.emit_stage_reductions`) resolves to a module
and then to its attributes, so a page cannot keep naming a function that was renamed or
removed. File names in backticks (`bench.json`) are not names."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FILES = {"md", "json", "png", "spr", "py", "npz", "csv", "cir", "txt", "wav", "lark", "npy",
         "sh", "toml", "cfg", "nbi", "nbc", "pkl", "flac", "ogg"}
NAME = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)+)`")


def _modules() -> dict[str, str]:
    """Every package and module of springc by its own name -> its dotted path (names that
    two modules share are left out: a page must say which)."""
    found: dict[str, list[str]] = {}
    for path in (ROOT / "springc").rglob("*.py"):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        found.setdefault(parts[-1], []).append(".".join(parts))
    return {k: v[0] for k, v in found.items() if len(v) == 1}


SHORT = _modules()


def names(page: Path) -> list[str]:
    """The dotted names in backticks on `page` that start at springc or one of its parts."""
    out = []
    for name in NAME.findall(page.read_text()):
        head, _, rest = name.partition(".")
        if name.rsplit(".", 1)[1] in FILES:
            continue
        if head == "springc":
            out.append(name)
        elif head in SHORT:
            out.append(f"{SHORT[head]}.{rest}")
    return sorted(set(out))


def resolves(dotted: str) -> bool:
    """Whether the longest importable module prefix of `dotted` has the rest as attributes."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_named_symbol_exists(page: Path) -> None:
    missing = [n for n in names(page) if not resolves(n)]
    assert not missing, f"{page.name} names what does not exist: {missing}"
