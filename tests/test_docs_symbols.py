"""Every `module.symbol` the user and architecture pages name in backticks exists: a span
whose first part is a springc module (by its last dotted names, `codegen`, `sim.gpu`, the
CLI's `cli/` as `cli`) or a springc class (`KernelOptions.fma`) must resolve attribute by
attribute, dataclass fields included. Spans that start with anything else (`xarray.Dataset`,
a netlist path `X1.a`, a variable `res.points`) are not springc's to check."""

from __future__ import annotations

import importlib
import pkgutil
import re
from functools import cache
from pathlib import Path

import pytest

import springc
import springc_cli

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", "docs/architecture.md", "docs/api.md", "docs/language.md",
         "docs/glossary.md", "docs/keyword-spotting.md"]
SPAN = re.compile(r"`([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+)(?:\(\))?`")
FILE = re.compile(r"\.(py|md|lark|spr|json|png|sh|txt|npz|csv|wav|cir|toml|pkl)$")


@cache
def modules() -> dict[tuple[str, ...], str]:
    """Each springc module's dotted name as a tuple (the CLI package as `cli`) -> name."""
    out = {}
    for pkg in (springc, springc_cli):
        names = [pkg.__name__] + [i.name for i in pkgutil.walk_packages(
            pkg.__path__, pkg.__name__ + ".")]
        for name in names:
            out[tuple(name.replace("springc_cli", "cli").split("."))] = name
    return out


@cache
def classes() -> dict[str, list[type]]:
    """Every class defined in a springc module, by name."""
    out: dict[str, list[type]] = {}
    for name in modules().values():
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if isinstance(obj, type) and obj.__module__ == name:
                out.setdefault(attr, []).append(obj)
    return out


def _has(obj: object, parts: list[str]) -> bool:
    for part in parts:
        if part in getattr(obj, "__dataclass_fields__", {}) and not hasattr(obj, part):
            return part == parts[-1]  # a field without a default: no attribute below it
        if not hasattr(obj, part):
            return False
        obj = getattr(obj, part)
    return True


def verdict(span: str) -> bool | None:
    """True where `span` resolves, False where it starts with a springc module or class and
    does not, None where it is not springc's."""
    parts = span.split(".")
    owners = []
    for key, name in modules().items():
        for i in range(min(len(parts), len(key)), 0, -1):
            if key[-i:] == tuple(parts[:i]):
                owners.append((importlib.import_module(name), parts[i:]))
    owners += [(cls, parts[1:]) for cls in classes().get(parts[0], [])]
    if not owners:
        return None
    return any(_has(obj, rest) for obj, rest in owners)


def spans() -> list[tuple[str, int, str]]:
    found = []
    for page in PAGES:
        for n, line in enumerate((ROOT / page).read_text().splitlines(), 1):
            found += [(page, n, m.group(1)) for m in SPAN.finditer(line)
                      if not FILE.search(m.group(1))]
    return found


def test_pages_name_symbols_at_all() -> None:
    # the check must see the pages' symbols, not skip them all
    assert sum(verdict(span) is True for _, _, span in spans()) >= 100


def test_every_named_symbol_exists() -> None:
    missing = [f"{page}:{n}: `{span}`" for page, n, span in spans() if verdict(span) is False]
    assert not missing, "named in the pages but not in the code:\n" + "\n".join(missing)


@pytest.mark.parametrize("span, expected", [
    ("codegen.stage_terms", True), ("codegen._emit_stage_reductions", False),
    ("KernelOptions.fma", True), ("KernelOptions.nope", False), ("xarray.Dataset", None)])
def test_the_check_tells_names_apart(span: str, expected: bool | None) -> None:
    assert verdict(span) is expected
