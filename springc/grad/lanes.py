"""The adjoint kernels compiled for a fixed number of lanes.

`springc.grad.adjoint` reads its lane count from its arrays and loops over the lanes.
`module(L)` writes a copy of the adjoint module with `LANES = L` and its lane loops unrolled
statement by statement (`source`), so that LLVM's SLP vectoriser packs the lanes into
vector arithmetic, to the kernel cache folder
(`springc.kernels.loader.cache_dir`, a real file so numba caches its machine code beside it)
and imports it; `call(fn, ...)` runs one of its functions with the SLP vectoriser on while
the first call compiles (as the generated kernels do).
"""

from __future__ import annotations

import ast
import copy
import hashlib
import importlib.util
import os
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

from springc.grad import render
from springc.kernels.loader import cache_dir, compiling, on_own_thread

CHOICES = (8, 4, 2, 1)  # lane counts compiled (each is a compile of its own)
_LOADED: dict[int, ModuleType] = {}
_LOCK = threading.Lock()
_LOCK_SOURCE = threading.Lock()


def choose(runs_per_thread: int) -> int:
    """The widest lane count of `CHOICES` that a thread's share of the runs fills."""
    return next(w for w in CHOICES if runs_per_thread >= w)


def module(lanes: int) -> ModuleType:
    """The adjoint module compiled for `lanes` lanes (loaded once per process)."""
    with _LOCK:
        if lanes not in _LOADED:
            _LOADED[lanes] = _load(lanes)
        return _LOADED[lanes]


def _load(lanes: int) -> ModuleType:
    return load_source(source(lanes), "springc_grad_adjoint")


def load_source(text: str, prefix: str) -> ModuleType:
    """Write a generated module's `text` to the kernel cache folder (named by `prefix` and
    its hash; a real file, so numba caches machine code beside it) and import it."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    name = f"{prefix}_{digest}"
    with _LOCK_SOURCE:
        if name not in sys.modules:
            sys.modules[name] = _import(text, name)
        return sys.modules[name]


def _import(text: str, name: str) -> ModuleType:
    path = cache_dir() / f"{name}.py"
    if not path.exists():  # whole or absent: written beside, then renamed into place
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    mod.COMPILED = set()
    return mod


def source(lanes: int) -> str:
    """The adjoint module's text with `LANES = lanes`, its force functions rendered from the
    element kinds (`render.loop_source`) and every lane loop unrolled."""
    # its text, not the module: importing it would import numba and compile nothing of use
    text = Path(importlib.util.find_spec("springc.grad.adjoint").origin).read_text()
    marker = "\nLANES = 0\n"
    if marker not in text:
        raise RuntimeError("springc.grad.adjoint has lost its `LANES = 0` line")
    text = text.replace(marker, f"\nLANES = {lanes}\n", 1) + render.loop_source()
    tree = ast.parse(text)
    tree = ast.fix_missing_locations(_Unroll(lanes).visit(tree))
    return f"# springc.grad.adjoint for {lanes} lane(s), generated: do not edit\n" + \
        ast.unparse(tree) + "\n"


class _Unroll(ast.NodeTransformer):
    """`for b in range(...)` (b is the lane everywhere in the adjoint module) becomes its
    body statement by statement, each statement once per lane with b a constant and the
    loop's own scalars renamed per lane. Lanes touch only their own column, so any order of
    their statements is the loop's; statement by statement, every lane's loads of one
    statement come before its stores, which lets the SLP vectoriser pack the lanes (a
    store of lane 0 before a load of lane 1 through another array would not)."""

    def __init__(self, lanes: int) -> None:
        self.lanes = lanes
        self.temps = 0

    def visit_For(self, node: ast.For):
        self.generic_visit(node)
        if not (isinstance(node.target, ast.Name) and node.target.id == "b") or node.orelse:
            return node
        return self.unroll(node.body, _assigned(node.body))

    def unroll(self, body: list, local: set[str]) -> list:
        out: list = []
        for stmt in body:
            lane_free = lambda expr: not (_names(expr) & (local | {"b"}))  # noqa: E731
            if isinstance(stmt, ast.If) and lane_free(stmt.test):
                out.append(ast.If(stmt.test, self.unroll(stmt.body, local) or [ast.Pass()],
                                  self.unroll(stmt.orelse, local)))
            elif isinstance(stmt, ast.For) and lane_free(stmt.iter) and not stmt.orelse:
                out.append(ast.For(stmt.target, stmt.iter, self.unroll(stmt.body, local), [],
                                   None))
            else:
                copies = [_Lane(k, local).visit(copy.deepcopy(stmt)) for k in range(self.lanes)]
                out += self.loads_first(copies)
        return out

    def loads_first(self, copies: list) -> list:
        """Stores to arrays as `t_k = value` for every lane, then `target_k = t_k`: all
        the lanes' loads come before their stores."""
        if not all(_array_store(c) for c in copies):
            return copies
        self.temps += 1
        names = [f"_t{self.temps}_l{k}" for k in range(len(copies))]
        values = [c.value if isinstance(c, ast.Assign)
                  else ast.BinOp(_read(c.target), c.op, c.value) for c in copies]
        targets = [c.targets[0] if isinstance(c, ast.Assign) else c.target for c in copies]
        return ([ast.Assign([ast.Name(n, ast.Store())], v) for n, v in zip(names, values)]
                + [ast.Assign([t], ast.Name(n, ast.Load())) for n, t in zip(names, targets)])


class _Lane(ast.NodeTransformer):
    """One lane's copy of a statement: b -> k, the loop's scalars -> name_l<k>."""

    def __init__(self, lane: int, local: set[str]) -> None:
        self.lane, self.local = lane, local

    def visit_Name(self, node: ast.Name):
        if node.id == "b":
            return ast.copy_location(ast.Constant(self.lane), node)
        if node.id in self.local:
            return ast.copy_location(ast.Name(f"{node.id}_l{self.lane}", node.ctx), node)
        return node


def _assigned(body: list) -> set[str]:
    """Names a loop body assigns (not the targets of its own loops, shared by the lanes)."""
    out: set[str] = set()
    for node in ast.walk(ast.Module(body, [])):
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AugAssign):
            targets = [node.target]
        else:
            continue
        for target in targets:
            out |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)
                    and isinstance(n.ctx, ast.Store)}
    return out


def _array_store(stmt) -> bool:
    """An assignment of one value to one array element (`a[i, 0] = ...`, `a[i, 0] += ...`)."""
    if isinstance(stmt, ast.Assign):
        return len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Subscript)
    return isinstance(stmt, ast.AugAssign) and isinstance(stmt.target, ast.Subscript)


def _read(target: ast.Subscript) -> ast.Subscript:
    """The element a store writes, read."""
    return ast.Subscript(copy.deepcopy(target.value), copy.deepcopy(target.slice), ast.Load())


def _names(expr) -> set[str]:
    return {n.id for n in ast.walk(expr) if isinstance(n, ast.Name)}


def call(mod: ModuleType, name: str, *args) -> None:
    """mod.name(*args); its first call per process compiles (or loads from numba's cache)
    under the file's lock with the SLP vectoriser on (`loader.compiling`), on a thread of
    its own (`loader.on_own_thread`)."""
    fn = getattr(mod, name)
    if name not in mod.COMPILED:
        with compiling(Path(mod.__file__)):
            on_own_thread(lambda: fn(*args))
        mod.COMPILED.add(name)
        return
    fn(*args)
