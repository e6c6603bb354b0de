"""The physics checks of a flat netlist (docs/language.md, "What the checks refuse").

Passes, in order: element signs, nodes without mass, the whole potential (only components
with `P` elements can violate it: every other element is non-negative on its own), and the
time step of the configured integrator against the linearisation at rest (for a splitting
scheme of `springc.kernels.expint`: of what its Runge-Kutta part integrates). Each finding is a
`Diagnostic` at the element's source location with a hint; later passes run only when the
earlier ones found no error (they need positive masses and a sound potential).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from springc.kernels import expint
from springc.check import linear, sparse
from springc.errors import CheckError, Diagnostic, SourceLoc
from springc.kernels.integrators import DEFAULT_METHOD
from springc.lang.ir import FlatNetlist
from springc.lang.options import OptionValueError, known_methods, method_name


@dataclass
class CheckResult:
    """All diagnostics, and the linear analysis computed on the way (None if not reached)."""

    diagnostics: list[Diagnostic]
    modes: linear.Modes | None = None
    step: linear.StepLimit | None = None
    method: str = DEFAULT_METHOD
    tstep: float | None = None  # effective step: .tran tstep / substeps
    blocks: expint.Blocks | None = None  # what a splitting scheme integrates exactly
    pinned: bool = False  # the caller or .options named the integrator (`pinned`)

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.diagnostics if d.severity == "error"]

    @property
    def notes(self) -> list[Diagnostic]:
        """Warnings and infos."""
        return [d for d in self.diagnostics if d.severity != "error"]


_SEAL = object()  # only `check` makes a CheckedNetlist


@dataclass
class CheckedNetlist(CheckResult):
    """A netlist that passed every check, with what the checks computed: the only input that
    kernels, the simulator, the analyses and the exporter accept. Made by `check` alone."""

    net: FlatNetlist | None = None
    seal: object = field(default=None, repr=False, compare=False)
    limits: dict = field(default_factory=dict, repr=False, compare=False)
    # its key in the check cache (`springc.check.store`), where it was stored or loaded
    entry: str | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.seal is not _SEAL or self.net is None:
            raise TypeError("a CheckedNetlist comes from springc.check.check(net) alone")

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "seal"}

    def __setstate__(self, state: dict) -> None:
        """Unpickled (`springc.check.store` keeps what `check` made): sealed again."""
        self.__dict__.update(state, seal=_SEAL)

    def step_limit(self, method: str) -> linear.StepLimit:
        """Largest stable step of `method` (computed once per method)."""
        if method == self.method and self.step is not None:
            return self.step
        if method not in self.limits:
            self.limits[method] = step_limit(self.net, method, self.modes)
        return self.limits[method]

    def require_stable(self, method: str, h: float, substeps: int) -> None:
        """Raise `CheckError` with `springc build`'s located message if the step `h` of
        `method` is above its stability limit."""
        limit = self.step_limit(method)
        if not h <= limit.dt * (1 + 1e-9):
            raise CheckError([_unstable(self.net, method, h, substeps, limit)])


def require_stable_many(members: list[CheckedNetlist], method: str, h: float,
                        substeps: int) -> list[CheckError | None]:
    """`require_stable` of every member, each result its `CheckError` or None: the limits
    of a Runge-Kutta `method` not yet known are computed for all members in one vectorised
    pass (`linear.step_limits`, each the same as alone), which is what keeps a population
    of 10^4 points' checks at a fraction of its simulation."""
    if not expint.is_split(method):
        todo = [m for m in members if m.modes is not None and method not in m.limits
                and not (method == m.method and m.step is not None)]
        for member, limit in zip(todo, linear.step_limits([m.modes for m in todo], method)):
            member.limits[method] = limit
    found: list[CheckError | None] = []
    for member in members:
        try:
            member.require_stable(method, h, substeps)
            found.append(None)
        except CheckError as err:
            found.append(err)
    return found


def check(net: FlatNetlist, method: str | None = None, *, tstep: float | None = None,
          substeps: int | None = None, judge_step: bool | None = None) -> CheckedNetlist:
    """Run every check; raise `CheckError` with all error diagnostics if there is any, else
    return the checked netlist. `method`, `tstep` and `substeps` override `.options` and
    `.tran` (the step a simulation will take is the step judged). The step is judged where
    it is `pinned` (`judge_step=None`, the default): a step springc chooses is judged when
    the simulator takes it. `judge_step=True` judges the configured step always, `False`
    never (the bench's ladders run above the limit on purpose)."""
    result = diagnose(net, method, tstep=tstep, substeps=substeps, judge_step=judge_step)
    if result.errors:
        raise CheckError(result.errors)
    return CheckedNetlist(**vars(result), net=net, seal=_SEAL)


def check_many(nets: list[FlatNetlist], method: str | None = None, *,
               tstep: float | None = None, substeps: int | None = None,
               judge_step: bool | None = None) -> list[CheckedNetlist | CheckError]:
    """`check` of every netlist (arguments as `check`), each result the checked netlist or
    the `CheckError` that `check` raises; the modes of all that reach the time step are
    computed together (`linear.modes_many`: the points of a population share the work of
    their Lanczos runs, and a large component close to the first of its size takes its
    certified bound from that one's, `near`). Each is refused exactly where it is refused
    alone: a step judged unstable against a bound by perturbation is judged again against
    the netlist's own."""
    results = _before_steps(nets)
    going = [i for i, result in enumerate(results) if result is None]
    found = dict(zip(going, linear.modes_many([nets[i] for i in going], near=True)))
    for i, result in _time_steps(nets, going, found, method, tstep, substeps, judge_step):
        results[i] = result
    again = [i for i in going if results[i].errors and found[i].near]
    found.update(zip(again, linear.modes_many([nets[i] for i in again])))
    for i, result in _time_steps(nets, again, found, method, tstep, substeps, judge_step):
        results[i] = result
    return [CheckError(r.errors) if r.errors else CheckedNetlist(**vars(r), net=net, seal=_SEAL)
            for r, net in zip(results, nets)]


def _time_steps(nets: list[FlatNetlist], which: list[int], found: dict, method: str | None,
                tstep: float | None, substeps: int | None,
                judge: bool | None) -> list[tuple[int, CheckResult]]:
    """`time_step` of the netlists `which` with their modes `found`, the step limits of each
    Runge-Kutta method computed for all of its netlists at once."""
    names = {i: _method(nets[i], method)[0] for i in which}
    limits = {}
    for name in {n for n in names.values() if not expint.is_split(n)}:
        ours = [i for i in which if names[i] == name]
        limits.update(zip(ours, linear.step_limits([found[i] for i in ours], name)))
    return [(i, time_step(nets[i], method, tstep=tstep, substeps=substeps, judge=judge,
                          found=found[i], step=limits.get(i))) for i in which]


def require_checked(value: object, who: str) -> CheckedNetlist:
    """`value` if it is a checked netlist, else a TypeError telling the caller to check."""
    if not isinstance(value, CheckedNetlist):
        raise TypeError(f"{who} takes a CheckedNetlist, not {type(value).__name__}: "
                        "call springc.check.check(net) first")
    return value


def diagnose(net: FlatNetlist, method: str | None = None, *, tstep: float | None = None,
             substeps: int | None = None, judge_step: bool | None = None) -> CheckResult:
    """Run every check and return all diagnostics without raising (arguments as `check`)."""
    early = _before_step(net)
    if early is not None:
        return early
    return time_step(net, method, tstep=tstep, substeps=substeps, judge=judge_step)


def _before_steps(nets: list[FlatNetlist]) -> list[CheckResult | None]:
    """`_before_step` of every netlist, the sign and range rules of the netlists of one
    pattern (`linear.pattern`) applied to their coefficients at once: a netlist they pass
    skips its own `element_signs`, which would find nothing."""
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(linear.patterns(nets)):
        groups.setdefault(key, []).append(i)
    out: list[CheckResult | None] = [None] * len(nets)
    for group in groups.values():
        clean = _signs_clean([nets[i] for i in group])
        for i, ok in zip(group, clean):
            out[i] = _before_step(nets[i], signs_clean=bool(ok))
    return out


def _before_step(net: FlatNetlist, signs_clean: bool = False) -> CheckResult | None:
    """The errors of the passes before the time step, None where there are none
    (`signs_clean`: `element_signs` is known to find nothing)."""
    signs = [] if signs_clean else element_signs(net)
    diags = signs + massless_nodes(net) + noise_sources(net)
    if diags:
        return CheckResult(diags)
    diags = whole_potential(net)
    if diags:
        return CheckResult(diags)
    return None


# --- element signs ----------------------------------------------------------------------

def _rules(net: FlatNetlist):
    """(letter, failing mask, message template, values, hint) for every sign rule."""
    m, k, d, c, q, b = (net.masses, net.springs, net.duffings, net.couplings, net.quads,
                        net.dashpots)
    with np.errstate(divide="ignore", invalid="ignore"):
        c_ratio, q_ratio = c.k / c.a, q.g / q.a
    return [
        ("M", ~(m.m > 0), "mass m={:g} must be > 0", m.m, "every mass must be positive"),
        ("M", ~(m.b >= 0), "damping b={:g} must be >= 0", m.b,
         "negative damping feeds energy in; use b=0 for no damping"),
        ("K", ~(k.k >= 0), "stiffness k={:g} must be >= 0", k.k,
         "a negative spring makes the rest state unstable"),
        ("D", ~(d.l >= 0), "Duffing coefficient l={:g} must be >= 0", d.l,
         "V = l/4 x^4 with l < 0 is unbounded below"),
        ("C", ~(c.a != 0), "leverage a={:g} must be != 0", c.a,
         "V = k/(2a) (x_i - a x_j)^2 divides by a"),
        ("C", (c.a != 0) & ~(c_ratio >= 0), "k/a={:g} must be >= 0", c_ratio,
         "k and a must have the same sign"),
        ("Q", ~(q.a != 0), "leverage a={:g} must be != 0", q.a,
         "V = g/(2a) (x_i^2 - a x_j)^2 divides by a"),
        ("Q", (q.a != 0) & ~(q_ratio >= 0), "g/a={:g} must be >= 0", q_ratio,
         "g and a must have the same sign"),
        ("B", ~(b.b >= 0), "dashpot b={:g} must be >= 0", b.b,
         "negative damping feeds energy in"),
    ]


@dataclass
class _Stacked:
    """The coefficients of netlists of one pattern, each column stacked to (netlists,
    elements), under the table names `_rules` and `_magnitudes` read."""

    masses: object
    springs: object
    duffings: object
    couplings: object
    quads: object
    dashpots: object
    monomials: object

    @classmethod
    def of(cls, nets: list[FlatNetlist]) -> _Stacked:
        from types import SimpleNamespace

        def table(name: str, *keys: str) -> SimpleNamespace:
            return SimpleNamespace(**{k: np.array([getattr(getattr(n, name), k) for n in nets])
                                      for k in keys})

        return cls(table("masses", "m", "b"), table("springs", "k"), table("duffings", "l"),
                   table("couplings", "k", "a"), table("quads", "g", "a"),
                   table("dashpots", "b"), table("monomials", "c"))

    def tables(self) -> dict[str, object]:
        return {"M": self.masses, "K": self.springs, "D": self.duffings, "C": self.couplings,
                "Q": self.quads, "B": self.dashpots, "P": self.monomials}


def _signs_clean(nets: list[FlatNetlist]) -> np.ndarray:
    """Per netlist (all of one pattern): whether `element_signs` finds nothing, from the
    rules applied to the coefficients of all of them at once."""
    if (nets[0].monomials.exp < 0).any():
        return np.zeros(len(nets), bool)
    stacked = _Stacked.of(nets)
    bad = np.zeros(len(nets), bool)
    with np.errstate(invalid="ignore"):
        for _, mask, *_ in _rules(stacked):
            bad |= mask.reshape(len(nets), -1).any(axis=1)
        tables = stacked.tables()
        for letter, key in _RANGED:
            values = getattr(tables[letter], key)
            bad |= _out_of_range(values).reshape(len(nets), -1).any(axis=1)
    return ~bad


def element_signs(net: FlatNetlist) -> list[Diagnostic]:
    """One error per element that breaks a sign rule of the element table."""
    tables = net.tables()
    out = []
    for letter, bad, template, values, hint in _rules(net):
        for e in np.nonzero(bad)[0]:
            table = tables[letter]
            msg = f"{table.names[e]}: {template.format(values[e])}"
            out.append(Diagnostic("error", msg, table.locs[e], hint))
    return out + _magnitudes(net) + _exponents(net)


SCALE_LIMIT = 1e150  # the checks multiply two coefficients (k/m, b^2): both must stay finite
_RANGED = [("M", "m"), ("M", "b"), ("K", "k"), ("D", "l"), ("C", "k"), ("C", "a"),
           ("Q", "g"), ("Q", "a"), ("B", "b"), ("P", "c")]


def _out_of_range(values: np.ndarray) -> np.ndarray:
    """Where a coefficient is so large or so small (but not 0) that a product of two leaves
    the doubles."""
    size = np.abs(values)
    return (size > SCALE_LIMIT) | ((size > 0) & (size < 1 / SCALE_LIMIT))


def _magnitudes(net: FlatNetlist) -> list[Diagnostic]:
    """Coefficients so large or so small (but not 0) that their products leave the doubles."""
    tables = net.tables()
    out = []
    for letter, key in _RANGED:
        values = getattr(tables[letter], key)
        for e in np.nonzero(_out_of_range(values))[0]:
            msg = (f"{tables[letter].names[e]}: {key}={values[e]:g} is outside the range "
                   f"1e-150..1e150 that the checks can square")
            out.append(Diagnostic("error", msg, tables[letter].locs[e],
                                  "rescale the units (for example um and us instead of m and s)"))
    return out


def _exponents(net: FlatNetlist) -> list[Diagnostic]:
    p = net.monomials
    out = []
    for k in np.nonzero(p.exp < 0)[0]:
        e = int(np.searchsorted(p.ptr, k, side="right") - 1)
        msg = (f"{p.names[e]}: exponent {int(p.exp[k])} of {net.nodes[p.var[k]]} must be a "
               f"non-negative integer")
        out.append(Diagnostic("error", msg, p.locs[e], "P elements are polynomials"))
    return out


# --- nodes without mass ----------------------------------------------------------------

def massless_nodes(net: FlatNetlist) -> list[Diagnostic]:
    """An error for every node that no `M` element declares, at the first element naming it."""
    has_mass = np.zeros(net.n, bool)
    has_mass[net.masses.node] = True
    out = []
    for node in np.nonzero(~has_mass)[0]:
        name, loc = _first_mention(net, int(node))
        node_name = net.nodes[node]
        msg = f"node '{node_name}' has no mass (named by {name}, but no M element declares it)"
        hint = f"add an M element on '{node_name}', e.g. 'M_{node_name} {node_name} m=1'"
        out.append(Diagnostic("error", msg, loc, hint))
    return out


# --- thermal noise -----------------------------------------------------------------------

def noise_sources(net: FlatNetlist) -> list[Diagnostic]:
    """An error where the netlist asks for thermal noise (`.noise`, `.options temp=` above
    0 K) but has no damper with b > 0 to make it."""
    if (net.masses.b > 0).any() or (net.dashpots.b > 0).any():
        return []
    hint = "give a mass a damping b= or add a B dashpot: thermal noise comes from dissipation"
    out = [Diagnostic("error", ".noise: the netlist has no damper, so no thermal noise",
                      spec.loc, hint) for spec in net.noises]
    if float(net.options.get("temp", 0.0)) > 0:
        out.append(Diagnostic("error", f"temp={net.options['temp']:g} K turns on thermal "
                              "noise, but the netlist has no damper",
                              net.option_locs.get("temp"), hint))
    return out


def _first_mention(net: FlatNetlist, node: int) -> tuple[str, SourceLoc]:
    """Name and location of the element or probe that names `node` first in the source."""
    found = []
    columns = {"K": ["node"], "D": ["node"], "C": ["i", "j"], "Q": ["i", "j"], "B": ["i", "j"],
               "F": ["node"]}
    tables = net.tables()
    for letter, cols in columns.items():
        table = tables[letter]
        for col in cols:
            for e in np.nonzero(getattr(table, col) == node)[0]:
                found.append((table.names[e], table.locs[e]))
    p = net.monomials
    for k in np.nonzero(p.var == node)[0]:
        e = int(np.searchsorted(p.ptr, k, side="right") - 1)
        found.append((p.names[e], p.locs[e]))
    found += [(f"probe {pr.label}", pr.loc) for pr in net.probes if pr.node == node]
    if not found:
        return f"node '{net.nodes[node]}'", net.node_locs[node]
    return min(found, key=lambda f: (f[1].file != net.file, f[1].line, f[1].col))


# --- whole potential -------------------------------------------------------------------

def whole_potential(net: FlatNetlist) -> list[Diagnostic]:
    """Positive semidefinite stiffness at rest and V bounded below, for every connected
    component that holds a `P` element (the only elements that can break either)."""
    p = net.monomials
    if len(p) == 0:
        return []
    _, labels = linear.component_labels(net)
    lin = linear.linearise(net)
    firsts = {}
    for e in range(len(p)):
        if p.ptr[e + 1] > p.ptr[e]:
            firsts.setdefault(int(labels[p.var[p.ptr[e]]]), e)
    out = []
    for comp, e in firsts.items():
        found = _component_potential(net, lin, labels, comp)
        if found:
            out.append(Diagnostic("error", f"{p.names[e]}: {found[0]}", p.locs[e], found[1]))
    return out


def _component_potential(net, lin, labels: np.ndarray, comp: int) -> tuple[str, str] | None:
    """(message, hint) if the potential restricted to this component is not acceptable."""
    nodes = np.nonzero(labels == comp)[0]
    hess = lin.K[nodes][:, nodes]
    negative = _negative_curvature(hess)
    if negative is not None:
        msg = (f"the stiffness matrix at rest is not positive semidefinite: curvature "
               f"{negative[0]:.6g} along {_direction(net, nodes, negative[1])}")
        return msg, "the rest state would be unstable; check the signs of the P coefficients"
    if _visibly_bounded(net, hess, labels, comp, nodes):
        return None
    direction = _escape(net, hess, labels, comp)
    if direction is None:
        return None
    msg = (f"the potential is not bounded below: V decreases without bound along "
           f"{_direction(net, nodes, direction, signed=True)}")
    return msg, ("add a higher even-order term (e.g. a D element) or fix the signs and "
                 "exponents of the P elements so that V stays bounded below")


def _visibly_bounded(net, hess, labels: np.ndarray, comp: int, nodes: np.ndarray) -> bool:
    """True when V >= 0 is evident, so no search is needed: every P term of the component is
    quadratic or a square (a positive coefficient, every exponent even), and the Hessian
    without the Q elements' share (g a on x_j) is PSD. Then V = 1/2 x.K'x + the Q and D
    potentials, each >= 0 by the sign rules (g/(2a)(x_i^2 - a x_j)^2, l/4 x^4), + the
    squares, which add nothing to the Hessian at rest; a network of designed zero modes, such
    as the classifier's multipliers, passes here instead of in a search over its hundreds of
    variables, and a population's points with such terms cost no search each."""
    import scipy.sparse as sp

    p, q = net.monomials, net.quads
    for e, (lo, hi) in enumerate(zip(p.ptr[:-1], p.ptr[1:])):
        if hi == lo or labels[p.var[lo]] != comp or p.exp[lo:hi].sum() == 2:
            continue
        if not (p.c[e] > 0 and (p.exp[lo:hi] % 2 == 0).all()):
            return False
    local = np.full(net.n, -1, np.int64)
    local[nodes] = np.arange(len(nodes))
    mine = labels[q.j] == comp
    share = np.zeros(len(nodes))
    np.add.at(share, local[q.j[mine]], q.g[mine] * q.a[mine])
    return _negative_curvature((hess - sp.diags(share)).tocsr()) is None


def _escape(net, hess, labels: np.ndarray, comp: int) -> np.ndarray | None:
    """A direction of unbounded descent of V = 1/2 x.K x + R(x) (R: the terms of degree other
    than 2), or None. The variables that occur only in quadratic terms are minimised out
    exactly (Schur complement), so the search runs over the few variables of R alone."""
    nodes = np.nonzero(labels == comp)[0]
    local = np.full(net.n, -1, np.int64)
    local[nodes] = np.arange(len(nodes))
    rest = _Polynomial.of_terms(len(nodes), (t for t in _terms(net, labels == comp, local)
                                             if sum(t[1].values()) != 2))
    keep = rest.variables()
    if len(keep) == 0:
        return None  # a PSD quadratic form
    schur, lift = _schur(hess, keep)
    index = np.full(len(nodes), -1, np.int64)
    index[keep] = np.arange(len(keep))
    pairs = [(c, {int(index[v]): e for v, e in pw.items()}) for c, pw in rest.terms()]
    pairs += [(schur[a, b] * (0.5 if a == b else 1.0), _mul({a: 1}, {b: 1}))
              for a in range(len(keep)) for b in range(a, len(keep)) if schur[a, b] != 0]
    reduced = _Polynomial.of_terms(len(keep), pairs)
    if reduced.degree() <= 2:
        scale = float(abs(hess).sum(axis=1).max())
        found = _quadratic_escape(reduced, *np.linalg.eigh(schur), scale)
    else:
        found = reduced.unbounded_direction()
    return None if found is None else lift @ found


def _schur(hess, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Schur complement of the Hessian onto `keep` (dense) and the map from kept variables to
    the minimising full vector (y = -Kyy^-1 Kys s; a tiny shift handles a singular Kyy, whose
    null space a PSD Hessian keeps out of Kys)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla

    n = hess.shape[0]
    other = np.setdiff1d(np.arange(n), keep)
    hess = hess.tocsr()
    kss = hess[keep][:, keep].toarray()
    lift = np.zeros((n, len(keep)))
    lift[keep, np.arange(len(keep))] = 1.0
    if len(other) == 0:
        return kss, lift
    kyy = hess[other][:, other].tocsc()
    kys = hess[other][:, keep].toarray()
    shift = 1e-12 * max(float(np.abs(kyy.diagonal()).max(initial=0.0)), 1e-300)
    solved = sla.splu((kyy + shift * sp.identity(len(other))).tocsc()).solve(kys)
    lift[other] = -solved
    return kss - kys.T @ solved, lift


# Components up to this size get every eigenvalue when refused (dense, about 1 s at 2000):
# shift-invert Lanczos does not converge on the many zero modes of the keyword-spotting
# classifier
PSD_DENSE_MAX = 2500
# Above this size a component is first tested sparsely (the measured crossover against dense
# eigenvalues: docs/performance.md, "Large networks")
PSD_SPARSE_FROM = 100
PSD_TOL = 1e-9  # eigenvalues below -PSD_TOL times the largest |eigenvalue| are negative


def _negative_curvature(hess) -> tuple[float, np.ndarray] | None:
    """The lowest eigenvalue of the Hessian at rest and its vector if it is negative beyond
    `PSD_TOL` of the largest |eigenvalue|, else None. A component above `PSD_SPARSE_FROM` is
    first tested for positive semidefiniteness by Gershgorin's discs, then by the inertia of
    one sparse LDL^T of the Hessian shifted by the tolerance (no negative pivot); only one
    that fails is solved for its lowest mode (`_lowest_stiffness`), which decides and gives
    the message."""
    n = hess.shape[0]
    if n > PSD_SPARSE_FROM:
        high = sparse.top(hess, 0, work=0).bound  # the scale of the tolerance only
        tol = PSD_TOL * max(high, 1e-300)
        if sparse.gershgorin(hess)[0].min() >= -tol:
            return None
        if sparse.Factor(hess, -tol).negative == 0:
            return None
    vals, vecs = _lowest_stiffness(hess)
    if vals[0] < -PSD_TOL * max(abs(vals).max(), 1e-300):
        return float(vals[0]), vecs[:, 0]
    return None


def _lowest_stiffness(hess) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs of the Hessian at rest, ascending: all of them for a small component, the
    lowest few for a large one (shift-invert Lanczos below the Gershgorin lower bound, so the
    nearest eigenvalues are the lowest ones), then the largest for the tolerance scale."""
    import scipy.sparse.linalg as sla

    n = hess.shape[0]
    if n <= PSD_DENSE_MAX:
        return np.linalg.eigh(hess.toarray())
    hess = hess.tocsc()
    low, high = (float(end) for end in (sparse.gershgorin(hess)[0].min(),
                                        sparse.gershgorin(hess)[1].max()))
    span = max(high - low, 1e-300)
    vals, vecs = sla.eigsh(hess, k=min(linear.SPARSE_MODES, n - 1),
                           sigma=min(low, 0.0) - 1e-6 * span, which="LM")
    order = np.argsort(vals)
    top = sla.eigsh(hess, k=1, sigma=high + 1e-6 * span, which="LM", return_eigenvectors=False)
    # The largest eigenvalue only sets the tolerance scale; its vector is never used.
    return np.append(vals[order], top), np.hstack([vecs[:, order], np.zeros((n, 1))])


def _quadratic_escape(poly: _Polynomial, vals: np.ndarray, vecs: np.ndarray,
                      scale: float) -> np.ndarray | None:
    """A PSD quadratic plus a linear term g.x is bounded below iff g has no part in the null
    space of the Hessian (eigenvalues below 1e-9 `scale`, the size of the whole component's
    Hessian); if it has, V falls linearly along minus that part."""
    g = poly.linear_part()
    null = vecs[:, vals <= 1e-9 * max(scale, 1e-300)]
    escape = -(null @ (null.T @ g))
    return escape if np.linalg.norm(escape) > 1e-9 * max(np.linalg.norm(g), 1e-300) else None


def _direction(net: FlatNetlist, nodes: np.ndarray, vec: np.ndarray, signed: bool = False,
               count: int = 4) -> str:
    """'x1=0.707, x2=0.707' for the largest components of a unit direction (its sign kept
    when `signed`, else chosen so that the largest component is positive)."""
    vec = vec / np.linalg.norm(vec)
    if not signed and vec[np.argmax(np.abs(vec))] < 0:
        vec = -vec
    order = np.argsort(-np.abs(vec), kind="stable")[:count]
    parts = [f"{net.nodes[nodes[j]]}={vec[j]:.3g}" for j in order if abs(vec[j]) > 1e-3]
    more = ", ..." if len(nodes) > count and abs(vec[order[-1]]) > 1e-3 else ""
    return "(" + ", ".join(parts) + more + ")"


@dataclass
class _Polynomial:
    """V restricted to one component: sum_t coef[t] prod_f x[var[t, f]]^exp[t, f] over `n`
    local variables (factor slots padded with exponent 0), so that memory stays O(terms)."""

    n: int
    coef: np.ndarray
    var: np.ndarray
    exp: np.ndarray

    @classmethod
    def of_terms(cls, n: int, pairs) -> _Polynomial:
        """Collect (coefficient, {var: power}) pairs over `n` variables, merging like terms."""
        terms: dict[tuple, float] = {}
        for coef, powers in pairs:
            key = tuple(sorted((v, e) for v, e in powers.items() if e))
            terms[key] = terms.get(key, 0.0) + coef
        keys = [k for k, v in terms.items() if v != 0]
        width = max((len(k) for k in keys), default=0)
        var = np.zeros((len(keys), width), np.int64)
        exp = np.zeros((len(keys), width), np.int64)
        for t, key in enumerate(keys):
            for f, (v, e) in enumerate(key):
                var[t, f], exp[t, f] = v, e
        return cls(n, np.array([terms[k] for k in keys], dtype=np.float64), var, exp)

    def variables(self) -> np.ndarray:
        """The variables that occur in some term, ascending."""
        return np.unique(self.var[self.exp > 0])

    def terms(self):
        """(coefficient, {var: power}) for every term."""
        for t in range(len(self.coef)):
            yield self.coef[t], {int(v): int(e) for v, e in zip(self.var[t], self.exp[t]) if e}

    def _factors(self, x: np.ndarray) -> np.ndarray:
        return x[self.var] ** self.exp

    def __call__(self, x: np.ndarray) -> float:
        return float(self.coef @ np.prod(self._factors(x), axis=1))

    def grad(self, x: np.ndarray) -> np.ndarray:
        factors = self._factors(x)
        out = np.zeros(self.n)
        for f in range(self.var.shape[1]):
            others = np.prod(np.delete(factors, f, axis=1), axis=1)
            slope = self.exp[:, f] * x[self.var[:, f]] ** np.maximum(self.exp[:, f] - 1, 0)
            np.add.at(out, self.var[:, f], self.coef * slope * others)
        return out

    def degree(self) -> int:
        return int(self.exp.sum(axis=1).max(initial=0))

    def linear_part(self) -> np.ndarray:
        """Coefficients g of the degree-1 terms: V = ... + g . x."""
        one = self.exp.sum(axis=1) == 1
        out = np.zeros(self.n)
        np.add.at(out, self.var[one, np.argmax(self.exp[one], axis=1)], self.coef[one])
        return out

    def magnitude(self, x: np.ndarray) -> float:
        """Sum of |term| at x: the scale against which round-off in V(x) is judged."""
        return float(np.abs(self.coef) @ np.abs(np.prod(self._factors(x), axis=1)))

    def top(self) -> _Polynomial:
        """The homogeneous part of the highest degree."""
        deg = self.exp.sum(axis=1)
        keep = deg == deg.max(initial=0)
        return _Polynomial(self.n, self.coef[keep], self.var[keep], self.exp[keep])

    def sphere_min(self, radius: float, starts: np.ndarray) -> tuple[float, np.ndarray]:
        """Smallest V on the sphere |x| = radius, by local searches from several starts."""
        def fun(y):
            norm = np.linalg.norm(y)
            u = y / norm
            g = self.grad(radius * u) * radius
            return self(radius * u), (g - u * (u @ g)) / norm
        best = (np.inf, starts[0])
        for y0 in starts:
            res = _minimize(fun, y0, jac=True, method="BFGS", options={"maxiter": 200})
            if res.fun < best[0]:
                best = (float(res.fun), res.x / np.linalg.norm(res.x))
        return best

    def unbounded_direction(self) -> np.ndarray | None:
        """A unit direction along which V decreases without bound, or None if V is bounded
        below. A top-degree part negative somewhere on the unit sphere gives it directly; one
        that is >= 0 but vanishes somewhere needs a search on growing spheres."""
        if len(self.coef) == 0:
            return None
        starts = _starts(self.n)
        top = self.top()
        scale = np.abs(top.coef).max()
        low, u = top.sphere_min(1.0, starts)
        if low < -1e-9 * scale:
            return u
        if low > 1e-6 * scale:
            return None
        return self._growing_spheres(starts, u)

    def _growing_spheres(self, starts: np.ndarray, hint: np.ndarray) -> np.ndarray | None:
        mins, u = [], hint
        for radius in 10.0 ** np.arange(-2, 7):
            low, u = self.sphere_min(radius, np.vstack([u, hint, starts]))
            # A minimum within round-off of zero is no evidence of descent.
            mins.append(low if low < -1e-10 * self.magnitude(radius * u) else 0.0)
        last = mins[-3:]
        falling = all(v < 0 for v in last) and last[1] < 1.5 * last[0] and last[2] < 1.5 * last[1]
        return u if falling else None


def _starts(n: int, seeds: int = 8) -> np.ndarray:
    """Seeded random directions plus the coordinate axes (both signs) for small n."""
    rng = np.random.default_rng(0)
    out = [rng.normal(size=(seeds, n))]
    if n <= 12:
        out += [np.eye(n), -np.eye(n)]
    return np.vstack(out)


def _terms(net: FlatNetlist, inside: np.ndarray, local: np.ndarray):
    """(coefficient, {local var: power}) for every potential term of the component whose
    nodes are marked in `inside` (elements are selected with masks, not visited one by one)."""
    s, d, c, q, p = net.springs, net.duffings, net.couplings, net.quads, net.monomials
    for e in np.nonzero(inside[s.node])[0]:
        yield s.k[e] / 2, {int(local[s.node[e]]): 2}
    for e in np.nonzero(inside[d.node])[0]:
        yield d.l[e] / 4, {int(local[d.node[e]]): 4}
    for e in np.nonzero(inside[c.i])[0]:
        i, j, k, a = int(local[c.i[e]]), int(local[c.j[e]]), c.k[e], c.a[e]
        yield from [(k / (2 * a), {i: 2}), (-k, _mul({i: 1}, {j: 1})), (k * a / 2, {j: 2})]
    for e in np.nonzero(inside[q.i])[0]:
        i, j, g, a = int(local[q.i[e]]), int(local[q.j[e]]), q.g[e], q.a[e]
        yield from [(g / (2 * a), {i: 4}), (-g, _mul({i: 2}, {j: 1})), (g * a / 2, {j: 2})]
    owner = np.repeat(np.arange(len(p)), np.diff(p.ptr))
    for e in np.unique(owner[inside[p.var]]):
        powers: dict[int, int] = {}
        for k in range(p.ptr[e], p.ptr[e + 1]):
            powers = _mul(powers, {int(local[p.var[k]]): int(p.exp[k])})
        yield p.c[e], powers


def _mul(a: dict[int, int], b: dict[int, int]) -> dict[int, int]:
    out = dict(a)
    for var, e in b.items():
        out[var] = out.get(var, 0) + e
    return out


# --- time step -------------------------------------------------------------------------

def _method(net: FlatNetlist, method: str | None) -> tuple[str, list[Diagnostic]]:
    raw = method or net.options.get("method", DEFAULT_METHOD)
    try:
        return method_name(raw), []
    except OptionValueError:
        loc = None if method else net.option_locs.get("method")
        msg = f"unknown integrator '{str(raw).lower()}'"
        return DEFAULT_METHOD, [Diagnostic("error", msg, loc,
                                           f"known: {', '.join(known_methods())}")]


def _substeps(net: FlatNetlist) -> tuple[int, list[Diagnostic]]:
    raw = net.options.get("substeps", 1)
    try:
        value = float(raw)
    except (TypeError, ValueError):
        value = float("nan")
    if value >= 1 and value == int(value):
        return int(value), []
    loc = net.option_locs.get("substeps")
    msg = f"substeps={raw} must be a positive integer"
    return 1, [Diagnostic("error", msg, loc, "the step is .tran tstep divided by substeps")]


def pinned(net: FlatNetlist, method: str | None = None, substeps: int | None = None) -> bool:
    """Whether the caller or the netlist's `.options` name the integrator or its substeps.
    Such a step is the user's and is judged when the netlist is checked; otherwise the
    simulator chooses the integration for an error tolerance (`accuracy.choose`)."""
    return bool(method or substeps or "method" in net.options or "substeps" in net.options)


def time_step(net: FlatNetlist, method: str | None = None, *, tstep: float | None = None,
              substeps: int | None = None, judge: bool | None = None,
              found: linear.Modes | None = None,
              step: linear.StepLimit | None = None) -> CheckResult:
    """Modes of the linearisation (`found`, computed if not given), zero modes as infos, and
    the configured step (`tstep` / `substeps` where given, else `.tran` and `.options`)
    against the integrator's stability limit (`step`, computed if not given), where `judge`
    says so (None: where the step is `pinned`)."""
    users = pinned(net, method, substeps)
    judge = users if judge is None else judge
    name, diags = _method(net, method)
    configured, more = _substeps(net)
    substeps = substeps or configured
    diags += more
    found = found if found is not None else linear.modes(net)
    blocks = expint.find_blocks(net) if expint.is_split(name) else None
    step = step if step is not None else step_limit(net, name, found, blocks)
    diags += [_zero_info(net, z) for z in found.zero_modes]
    tstep = tstep or (net.tran.tstep if net.tran else None)
    h = tstep / substeps if tstep else None
    if judge and h is not None and not h <= step.dt * (1 + 1e-9):
        diags.append(_unstable(net, name, h, substeps, step))
    return CheckResult(diags, found, step, name, h, blocks, users)


def step_limit(net: FlatNetlist, method: str, found: linear.Modes | None = None,
               blocks: expint.Blocks | None = None) -> linear.StepLimit:
    """Largest stable step of `method` and the mode that sets it. A Runge-Kutta tableau: over
    every mode of the linearisation (`found`, computed if not given). A splitting scheme
    (`expint`, blocks from `expint.find_blocks` if not given): see `split_step_limit`."""
    found = found if found is not None else linear.modes(net)
    if not expint.is_split(method):
        return linear.step_limit(found, method)
    return split_step_limit(net, method, found, blocks)


# --- time step of a splitting scheme ---------------------------------------------------
#
# The scheme integrates what the linearised `expint.split_netlist` holds with its inner
# Runge-Kutta method and the blocks exactly. That split, and not the full linearisation with
# the block modes removed, is the operator to judge: at rest a block meets the rest only
# through Q elements (a coupling or dashpot would have made the rest part of it), whose only
# linear term is a stiffness g a on their j node. On a rest node it is an ordinary rest mode.
# On a block node the Runge-Kutta part applies it to the block (a "kick"), which the full
# linearisation folds into a block mode and calls exact; and a Q joins a block and the rest
# into one component whose modes mix, so "the block modes" would need a guess from mode
# shapes. Without kicks the blocks impose no limit and the limit is the inner tableau's on the
# rest. A kicked block is judged by the scheme's own linear step map on it (Lawson: the kick
# at every stage through the exact flow; Strang: a velocity kick between two half flows, as
# block positions stay frozen in its Runge-Kutta step; below the inner tableau's limit on the
# kick alone: 0.7x for a 6 kHz kick on a 2 kHz filter). The map can be unstable in islands:
# a 3 kHz kick on a 7 kHz filter under exp-rk4 grows from h = 6.05e-5 s (16 kHz input: 6.25e-5)
# and is stable again at 1e-4 s, where the inner tableau on the kick alone allows 1.5e-4 s.
# The limit is the first step at which the map grows, as for the tableaux' own rays.

MAP_GRID = 2000  # steps tried per kicked block before bisection: narrower islands are missed


def split_step_limit(net: FlatNetlist, method: str, found: linear.Modes,
                     blocks: expint.Blocks | None = None) -> linear.StepLimit:
    """Largest stable step of the splitting scheme `method`: the inner tableau's limit over
    the rest's modes (block nodes left out), and for every block on whose nodes the rest puts
    a stiffness, the first step at which the scheme's linear step map on it grows."""
    import scipy.sparse as sp

    scheme = expint.SCHEMES[method]
    blocks = blocks if blocks is not None else expint.find_blocks(net)
    rest = expint.split_netlist(net, blocks)
    lin = linear.linearise(rest)
    inside = np.zeros(net.n, bool)
    inside[blocks.node_set()] = True
    keep = sp.diags((~inside).astype(float))
    # block rows and columns out: the rest's own modes (block nodes become free masses)
    outer = linear.Linearisation(lin.M, (keep @ lin.B @ keep).tocsr(),
                                 (keep @ lin.K @ keep).tocsr())
    limit = replace(linear.step_limit(linear.modes(rest, outer), scheme.inner), method=method)
    for k, kick in enumerate(block_kicks(net, blocks, lin)):
        if kick is None:
            continue
        h = _kicked_block_limit(scheme, blocks.a[k], kick, limit.dt)
        if h < limit.dt:
            limit = linear.StepLimit(method, h, _block_mode(found, blocks.nodes[k]))
    return limit


def block_kicks(net: FlatNetlist, blocks: expint.Blocks,
                lin: linear.Linearisation | None = None) -> list[np.ndarray | None]:
    """Per block, the stiffness per mass that the split's rest puts on its nodes at rest (the
    "kick", see below), or None where there is none. `lin`: the linearised
    `expint.split_netlist(net, blocks)`, computed if not given."""
    if lin is None:
        lin = linear.linearise(expint.split_netlist(net, blocks))
    minv = 1.0 / net.mass()
    kicks = [minv[nodes][:, None] * lin.K[nodes][:, nodes].toarray() for nodes in blocks.nodes]
    return [kick if kick.any() else None for kick in kicks]


def _kicked_block_limit(scheme: expint.SplitScheme, a: np.ndarray, kick: np.ndarray,
                        below: float) -> float:
    """First step h < `below` at which the spectral radius of the scheme's linear step map on
    one block (first-order matrix `a`, rest stiffness per mass `kick`) exceeds 1; `below` if
    none. An infinite `below` is capped at 8 / omega of the kick, past the stability
    boundary of any of our tableaux applied to the kick alone."""
    omega = math.sqrt(float(np.abs(np.linalg.eigvals(kick)).max()))
    if omega == 0.0:
        return below
    m = len(kick)
    # [x; v] -> [w x; v]: the same eigenvalues, and no w^2 against 1 in the exponent
    scale = math.sqrt(max(float(np.abs(a[m:, :m]).max()), omega**2))
    sim = np.concatenate([np.full(m, scale), np.ones(m)])
    a = a * sim[:, None] / sim[None, :]
    n = np.zeros_like(a)
    n[m:, :m] = -kick / scale
    top = min(below, 8.0 / omega)
    grid = top * np.arange(1, MAP_GRID + 1) / MAP_GRID
    grows = _map_radius(scheme, a, n, grid) > 1 + 1e-9
    if not grows.any():
        return below if top == below else top
    first = int(np.argmax(grows))
    low, high = (grid[first - 1] if first else 0.0), grid[first]
    for _ in range(50):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if _map_radius(scheme, a, n, np.array([mid]))[0] > 1 + 1e-9 \
            else (mid, high)
    return low


def _map_radius(scheme: expint.SplitScheme, a: np.ndarray, n: np.ndarray,
                h: np.ndarray) -> np.ndarray:
    """Spectral radius of the scheme's one-step map of z' = (a + n) z (a exact, n the kick)
    for every step in `h`."""
    hh = h[:, None, None]
    flow = _flow(a, hh)
    if scheme.kind == "strang":
        half = flow(scheme.half)
        step = half @ (np.eye(len(a)) + hh * n) @ half
    else:
        step = _lawson_map(scheme.tableau, flow, n, hh)
    return np.abs(np.linalg.eigvals(step)).max(axis=1)


def _flow(a: np.ndarray, hh: np.ndarray):
    """frac -> exp(a frac h) for every h of `hh` (shape (H, 1, 1)), cached per fraction: from
    the eigenvectors of `a` when they are well conditioned (thousands of steps at once),
    else scipy's expm one step at a time."""
    lam, vec = np.linalg.eig(a)
    diagonal = np.linalg.cond(vec) < 1e6
    inv = np.linalg.inv(vec) if diagonal else None
    cache: dict[float, np.ndarray] = {}

    def flow(frac: float) -> np.ndarray:
        import scipy.linalg

        if frac not in cache:
            if diagonal:
                grow = np.exp(lam[None, None, :] * (frac * hh))
                cache[frac] = ((vec[None] * grow) @ inv).real
            else:
                cache[frac] = scipy.linalg.expm(a[None] * (frac * hh))
        return cache[frac]

    return flow


def _lawson_map(tab, flow, n: np.ndarray, hh: np.ndarray) -> np.ndarray:
    """One Lawson step as a matrix: stage maps S_i = E(c_i h) + h sum_j a_ij E((c_i - c_j) h)
    n S_j, step E(h) + h sum_j b_j E((1 - c_j) h) n S_j (`expint`'s Lawson comment)."""
    stages = []
    for i, row in enumerate(tab.a):
        s_i = flow(tab.c[i])
        for j, aij in enumerate(row):
            if aij != 0.0:
                s_i = s_i + hh * aij * flow(tab.c[i] - tab.c[j]) @ n @ stages[j]
        stages.append(s_i)
    out = flow(1.0)
    for j, bj in enumerate(tab.b):
        if bj != 0.0:
            out = out + hh * bj * flow(1.0 - tab.c[j]) @ n @ stages[j]
    return out


def _block_mode(found: linear.Modes, nodes: np.ndarray) -> linear.Mode | None:
    """The fastest mode of the full linearisation that lies mostly on `nodes` (a block with
    the rest's stiffness on it), to name in messages."""
    best = None
    for k, (where, amps) in enumerate(found.shapes):
        w = np.abs(amps) ** 2
        on = np.isin(where, nodes)
        if w.sum() > 0 and w[on].sum() > 0.5 * w.sum() and (
                best is None or abs(found.eigenvalues[k]) > abs(found.eigenvalues[best])):
            best = k
    return found.mode(best) if best is not None else None


def _zero_info(net: FlatNetlist, zero: linear.ZeroModes) -> Diagnostic:
    loc = net.node_locs[net.nodes.index(zero.nodes[0][0])]
    hint = "legal (free bodies, matrix-vector multipliers); such motion is never restored"
    return Diagnostic("info", zero.describe(), loc, hint)


def _unstable(net, method: str, h: float, substeps: int, step: linear.StepLimit) -> Diagnostic:
    mode = step.mode.describe() if step.mode else "linearisation"
    sub = f" (tstep / substeps={substeps})" if substeps > 1 else ""
    msg = (f"time step {h:.6g} s{sub} is unstable for {method}: the {mode} needs a step "
           f"<= {step.dt:.6g} s (largest stable step)")
    if step.dt > 0:
        need = math.ceil(h / step.dt * (1 + 1e-9))
        hint = (f"use .tran tstep <= {step.dt * substeps:.6g}, or .options "
                f"substeps={need * substeps}")
    else:
        hint = f"{method} is unstable for this mode at any step; choose another method"
    return Diagnostic("error", msg, net.tran.loc if net.tran else None, hint)


def _minimize(*args, **kwargs):
    """scipy.optimize.minimize, imported when a P element's potential needs it (scipy.optimize
    costs a third of a second to import, and most netlists have no P element)."""
    from scipy.optimize import minimize

    return minimize(*args, **kwargs)
