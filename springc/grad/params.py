"""A netlist file as a function of its top-level `.param` values.

`ParamNetlist.load(path)` parses the file once (includes spliced in); `netlist(values)`
elaborates it with some parameters set to other values (each `.param` line of theirs at top
level replaced by the number, later parameters recomputed from it); `jacobian(values, wrt)`
gives d(coefficient)/d(parameter) for every element coefficient, exact to rounding, by
elaborating the tangent netlists of `springc.grad.derive`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.errors import NetlistError, SourceLoc, UsageError
from springc.lang import ast, read_source
from springc.lang.elaborate import elaborate
from springc.lang.parser import parse
from springc.lang.expr import Env, closest, value
from springc.lang.draws import Sample
from springc.lang.files import Includes
from springc.lang.ir import FlatNetlist
from springc.lang.variation import COEFFICIENTS, set_params, structure  # COEFFICIENTS: covered
from springc.grad.derive import tangent_tree

PROBE = 1e-3  # relative change of a parameter that must leave the netlist's structure alone


def coefficients(net: FlatNetlist) -> dict[tuple[str, str], np.ndarray]:
    """Every coefficient array of `net`, keyed as in `COEFFICIENTS`."""
    return {(t, f): np.asarray(getattr(getattr(net, t), f), np.float64) for t, f in COEFFICIENTS}


@dataclass
class ParamNetlist:
    """A parsed netlist with its top-level parameters: `values` (as the file sets them) and
    `locs` (where each is defined)."""

    file: str
    statements: list
    values: dict[str, float]
    locs: dict[str, SourceLoc]
    lib_dirs: list[Path] | None = None
    probed: set[str] = field(default_factory=set)  # parameters whose role `_probe` checked
    prefix: str | None = None  # of the derivative companions' names (`_prefix`)
    tangents: dict[str, list] = field(default_factory=dict)  # seed -> tangent statements

    @classmethod
    def load(cls, path: str | Path, lib_dirs: list[Path] | None = None) -> ParamNetlist:
        """Parse `path`, splice its includes and read its top-level parameters; the netlist
        must elaborate (a `NetlistError` otherwise)."""
        return cls.from_text(read_source(path), str(path), lib_dirs)

    @classmethod
    def from_text(cls, text: str, filename: str = "<text>",
                  lib_dirs: list[Path] | None = None) -> ParamNetlist:
        """As `load`, from source text."""
        tree = parse(text, filename)
        statements = Includes(lib_dirs).expand(tree)
        elaborate(ast.Netlist(filename, tuple(statements)), lib_dirs)
        values, locs = _top_params(statements)
        return cls(filename, statements, values, locs, lib_dirs)

    def require(self, names: Sequence[str], option: str = "--wrt") -> None:
        """A `UsageError` naming the option unless every name is a top-level `.param`."""
        for name in names:
            if name not in self.values:
                guess = closest(name, self.values)
                hint = (f"did you mean '{guess}'?" if guess else
                        f"top-level parameters: {', '.join(self.values) or 'none'}")
                raise UsageError(f"{option} {name}: {self.file} has no top-level .param "
                                 f"'{name}'", hint=hint)

    def netlist(self, values: Mapping[str, float] | None = None,
                sample: Sample | None = None) -> FlatNetlist:
        """The elaborated netlist with `values` replacing those parameters' definitions (in
        Monte Carlo `sample`: its draws, else the random functions' nominal values)."""
        values = dict(values or {})
        self.require(list(values), "parameter")
        return elaborate(self._tree(set_params(self.statements, values)), self.lib_dirs,
                         sample)

    def jacobian(self, values: Mapping[str, float] | None, wrt: Sequence[str],
                 sample: Sample | None = None
                 ) -> dict[str, dict[tuple[str, str], np.ndarray]]:
        """d(coefficient)/d(param) for each name of `wrt`, keyed as `coefficients()`, at the
        parameter values `values` (others as in the file), in Monte Carlo `sample` if given
        (each draw's unit deviate held fixed: `springc.grad.derive`). A parameter that no
        coefficient depends on, or that also sets something other than a coefficient (a
        source's arguments, a time, a loop bound, a node name), is a `UsageError`."""
        self.require(list(wrt))
        values = dict(values or {})
        base_stmts = set_params(self.statements, values)
        if any(name not in self.probed for name in wrt):
            base = elaborate(self._tree(base_stmts), self.lib_dirs)
        out = {}
        for name in wrt:
            if name not in self.probed:  # once per parameter: its role does not change
                self._probe(base, base_stmts, name)
                self.probed.add(name)
            try:
                out[name] = coefficients(elaborate(self._tangent(name, values), self.lib_dirs,
                                                   sample))
            except NetlistError as err:
                raise UsageError(f"cannot differentiate with respect to '{name}': "
                                 f"{err.format()}") from None
        return out

    def _tangent(self, seed: str, values: dict[str, float]) -> ast.Netlist:
        """The tangent netlist for `seed` at `values`: built once per seed from the file's
        statements, then the values set, each with its companion (1 for the seed, else 0:
        a number's derivative), as `tangent_tree` of the statements with the values set."""
        if seed not in self.tangents:
            self.tangents[seed] = list(tangent_tree(self.statements, self.file, seed,
                                                    self._prefix()).statements)
        companions = {self._prefix() + k: float(k == seed) for k in values}
        return self._tree(set_params(self.tangents[seed], {**values, **companions}))

    def _probe(self, base: FlatNetlist, stmts: list, name: str) -> None:
        """Elaborate with `name` nudged: the structure must stay, some coefficient must move."""
        current = _top_params(stmts)[0][name]
        nudged = current * (1 + PROBE) + PROBE
        try:
            moved = elaborate(self._tree(set_params(stmts, {name: nudged})), self.lib_dirs)
        except NetlistError:
            return  # a domain error at the nudged value: the tangent pass reports its own
        where = self.locs[name]
        if structure(moved) != structure(base):
            raise UsageError(f"--wrt {name}: the parameter sets more than element "
                             "coefficients (a source's arguments, a time, a loop bound or a "
                             "node name), which have no gradient here", where,
                             hint="use it only in m b x0 v0 k l a g c gain values")
        before, after = coefficients(base), coefficients(moved)
        if all(np.array_equal(before[k], after[k]) for k in before):
            raise UsageError(f"--wrt {name}: no element coefficient depends on the parameter",
                             where, hint="it is not used by any element")

    def _tree(self, statements: list) -> ast.Netlist:
        return ast.Netlist(self.file, tuple(statements))

    def _prefix(self) -> str:
        """A name prefix for the derivative companions that no name of the netlist uses
        (found once: the text of the whole tree is long)."""
        if self.prefix is None:
            text = repr(self.statements)
            self.prefix = "__d_"
            while self.prefix in text:
                self.prefix = "_" + self.prefix
        return self.prefix


def _top_params(statements: list) -> tuple[dict[str, float], dict[str, SourceLoc]]:
    """Values and locations of the top-level parameters, evaluated as the elaborator does
    (in order, `.data` arrays visible); only called on netlists that elaborate."""
    from springc.lang.files import beside, read_array

    env = Env()
    locs: dict[str, SourceLoc] = {}
    for stmt in statements:
        if not isinstance(stmt, ast.Directive):
            continue
        if stmt.name == "data":
            path = beside(stmt.args[1])
            env.vars[stmt.args[0].parts[0]] = read_array(path, stmt.args[1].loc)
        elif stmt.name == "param":
            for kw in stmt.args:
                env.vars[kw.key] = value(kw.value, env)
                locs[kw.key] = kw.loc
    values = {k: float(env.vars[k]) for k in locs}
    return values, locs
