"""springc's modules import one another in one direction: no import circle, lazy imports
inside functions included (a circle that only works because an import is deferred is still a
circle in the design). Inside `springc.kws` the subpackages import in the order of its flow,
data -> features -> training -> evaluation -> tuning: each only from its own or earlier ones."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def module_name(path: Path, top: Path) -> str:
    """Dotted module name of `path` under `top`'s parent (a package's `__init__` is the
    package)."""
    parts = list(path.relative_to(top.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(top: Path) -> dict[str, set[str]]:
    """Edges module -> project modules it imports (absolute and relative imports, nested ones
    included; `from package import module` points at the module)."""
    paths = {module_name(p, top): p for p in top.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in paths}
    for name, path in paths.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                    base = f"{anchor}.{base}" if base else anchor
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in paths else base
                           for a in node.names]
            else:
                continue
            graph[name] |= {t for t in targets if t in paths and t != name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected component of more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_springc_has_no_import_circle() -> None:
    assert circles(import_graph(ROOT / "springc")) == []


def test_a_circle_through_a_lazy_import_is_found(tmp_path: Path) -> None:
    top = tmp_path / "pkg"
    (top / "sub").mkdir(parents=True)
    (top / "__init__.py").write_text("")
    (top / "sub" / "__init__.py").write_text("")
    (top / "a.py").write_text("from pkg.sub import b\n")
    (top / "sub" / "b.py").write_text("def f():\n    from . import c\n")
    (top / "sub" / "c.py").write_text("import os\nfrom ..a import x\n")
    (top / "d.py").write_text("import pkg.a\n")
    assert circles(import_graph(top)) == [["pkg.a", "pkg.sub.b", "pkg.sub.c"]]


KWS_ORDER = ("data", "features", "training", "evaluation", "tuning")


def layer(module: str, package: str, order: tuple[str, ...]) -> int | None:
    """Position in `order` of the subpackage of `package` that holds `module`; len(order) for
    `package` itself (its `__init__` sits above every subpackage); None outside `package` or
    for a module of `package` in no listed subpackage."""
    if module == package:
        return len(order)
    if not module.startswith(package + "."):
        return None
    sub = module[len(package) + 1:].split(".")[0]
    return order.index(sub) if sub in order else None


def layer_violations(graph: dict[str, set[str]], package: str,
                     order: tuple[str, ...]) -> list[tuple[str, str]]:
    """Imports (module, imported) inside `package` that point to a later subpackage in
    `order`, or from or to a module of `package` in no listed subpackage."""
    def inside(module: str) -> bool:
        return module == package or module.startswith(package + ".")

    found = []
    for module in filter(inside, graph):
        here = layer(module, package, order)
        for target in filter(inside, graph[module]):
            there = layer(target, package, order)
            if here is None or there is None or there > here:
                found.append((module, target))
    return sorted(found)


def test_kws_subpackages_import_only_their_own_or_earlier_ones() -> None:
    graph = import_graph(ROOT / "springc")
    kws = sorted(m for m in graph if m.startswith("springc.kws."))
    assert len(kws) > len(KWS_ORDER)  # the graph holds the subpackages' modules
    assert [m for m in kws if layer(m, "springc.kws", KWS_ORDER) is None] == []
    assert layer_violations(graph, "springc.kws", KWS_ORDER) == []


def test_an_import_against_the_layer_order_is_found(tmp_path: Path) -> None:
    top = tmp_path / "pkg"
    for sub in ("early", "late"):
        (top / sub).mkdir(parents=True)
        (top / sub / "__init__.py").write_text("")
    (top / "__init__.py").write_text("from pkg.late import c\n")
    (top / "late" / "c.py").write_text("from ..early import a\n")
    (top / "early" / "a.py").write_text("from . import b\n")
    (top / "early" / "b.py").write_text("def f():\n    from pkg.late.c import g\n")
    (top / "stray.py").write_text("")
    (top / "early" / "d.py").write_text("import pkg.stray\nimport pkg\n")
    assert layer_violations(import_graph(top), "pkg", ("early", "late")) == [
        ("pkg.early.b", "pkg.late.c"), ("pkg.early.d", "pkg"), ("pkg.early.d", "pkg.stray")]
