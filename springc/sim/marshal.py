"""A checked netlist's kernel arrays: what the kernels read besides the state.

`coefficient_arrays` gives the force code's coefficient and index arrays (a population's at
once: `coefficient_columns`), `kernel_arrays` adds an exponential scheme's propagators, and
`lane_arrays` lays out the netlists of one structure in the lanes of one call (the arrays
that differ between them a column per run). The simulator (`springc.sim.simulate`) runs the
kernels on them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from springc.kernels import codegen, expint
from springc.kernels.lower import kernel_netlist
from springc.lang.ir import FlatNetlist
from springc.sim import reductions, sources, thermal



class Settings(Protocol):
    """What the arrays depend on of a simulation's settings (`simulate.Settings`)."""

    method: str
    precision: str

    @property
    def h(self) -> float: ...


# the arrays of `coefficient_arrays` that hold coefficients (the others index nodes and terms)
COEFFICIENT_KEYS = frozenset({"minv", "bm", "km", "d_lm", "l_val", "q_a", "q_gi", "q_gj",
                              "b_bi", "b_bj", "p_c", "fi_gm", "fc_gm"})


def coefficient_arrays(net: FlatNetlist, dtype) -> dict[str, np.ndarray]:
    """The kernel's coefficient and index arrays (names as in `codegen.accel_args`), with the
    inverse mass folded into every force coefficient (each end of an element over its own
    node's mass) and the linear springs and couplings as `linear_rows`."""
    columns = coefficient_columns([net], dtype)
    return {key: value[0] if key in COEFFICIENT_KEYS else value
            for key, value in columns.items()}


def coefficient_columns(nets: list[FlatNetlist], dtype) -> dict[str, np.ndarray]:
    """`coefficient_arrays` of netlists of one kernel pattern (`kernel_pattern`), computed
    for all at once: each coefficient array with a leading axis over the netlists (row s is
    netlist s's, bitwise what it has alone: the same operations in the same order), each
    index array once."""
    net = nets[0]
    f = lambda a: np.ascontiguousarray(a, dtype=dtype)  # noqa: E731
    i = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
    # node indices that are never negative: unsigned, so that numba indexes without its
    # negative-index wrap-around (4 instructions per index in the gather loops)
    u = lambda a: np.ascontiguousarray(a, dtype=np.uint64)  # noqa: E731

    def col(table: str, key: str) -> np.ndarray:
        return _column(nets, table, key)

    d, q, b, p = net.duffings, net.quads, net.dashpots, net.monomials
    fi, fc = sources.input_forces(net), sources.common_forces(net)
    force = net.forces
    chans = [force.source[e].channel for e in fi]
    minv = 1.0 / _per_node(net, col("masses", "m"))
    kdiag, l_ptr, l_col, l_val = linear_rows_many(nets, minv)
    ground = b.j < 0
    bj = np.where(ground, 0.0, col("dashpots", "b") * minv[:, np.where(ground, 0, b.j)])
    qg, qa, gain = col("quads", "g"), col("quads", "a"), col("forces", "gain")
    return {
        "minv": f(minv), "bm": f(_per_node(net, col("masses", "b")) * minv), "km": f(kdiag),
        "d_node": u(d.node), "d_lm": f(col("duffings", "l") * minv[:, d.node]),
        "l_ptr": u(l_ptr), "l_col": u(l_col), "l_val": f(l_val),
        "q_i": u(q.i), "q_j": u(q.j), "q_a": f(qa), "q_gi": f(2 * qg / qa * minv[:, q.i]),
        "q_gj": f(qg * minv[:, q.j]),
        "b_i": u(b.i), "b_j": i(b.j), "b_bi": f(col("dashpots", "b") * minv[:, b.i]),
        "b_bj": f(bj),
        "p_c": f(col("monomials", "c")), "p_ptr": i(p.ptr), "p_var": i(p.var),
        "p_exp": i(p.exp),
        "fi_node": u(force.node[fi]), "fi_gm": f(gain[:, fi] * minv[:, force.node[fi]]),
        "fi_chan": u(chans), "fi_ptr": u(np.searchsorted(force.node[fi], np.arange(net.n + 1))),
        "fc_node": u(force.node[fc]), "fc_gm": f(gain[:, fc] * minv[:, force.node[fc]]),
    }


def kernel_pattern(net: FlatNetlist) -> tuple:
    """What the index arrays of `coefficient_arrays` depend on: netlists with equal kernel
    patterns differ in their coefficient arrays alone."""
    from springc.check.linear import pattern

    sources_ = tuple((s.kind, s.channel) for s in net.forces.source)
    return pattern(net), net.forces.node.tobytes(), sources_


def _column(nets: list[FlatNetlist], table: str, key: str) -> np.ndarray:
    """(netlists, elements): coefficient `key` of element table `table` of every netlist."""
    return np.array([getattr(getattr(n, table), key) for n in nets], dtype=float)


def _per_node(net: FlatNetlist, values: np.ndarray) -> np.ndarray:
    """(netlists, n): each netlist's `M` values summed per node (`FlatNetlist.mass`)."""
    out = np.zeros((len(values), net.n))
    np.add.at(out, (slice(None), net.masses.node), values)
    return out


def linear_rows(net: FlatNetlist, minv: np.ndarray) -> tuple[np.ndarray, ...]:
    """The linear stiffness of springs and couplings over the mass, -M^-1 K, as a per-node
    diagonal (`km`, with the sign of a stiffness) and the off-diagonal rows in CSR form
    (`ptr`, `col`, `val`: acceleration of node i per unit x_col). The kernel gathers each
    node's row into registers and stores its acceleration once: a coupling pushed to both
    ends costs two loads and a store of the force rows per end (the kernel is memory-bound).
    A coupling k/(2a) (x_i - a x_j)^2 puts k/a on i's diagonal, k a on j's and -k off it."""
    diag, ptr, cols, vals = linear_rows_many([net], minv[None, :])
    return diag[0], ptr, cols, vals[0]


def linear_rows_many(nets: list[FlatNetlist], minv: np.ndarray) -> tuple[np.ndarray, ...]:
    """`linear_rows` of netlists of one pattern: `minv` with a leading axis over the
    netlists, as have the diagonal and values returned."""
    net = nets[0]
    s, c, n = net.springs, net.couplings, net.n
    rows = np.concatenate([s.node, c.i, c.j, c.i, c.j])
    cols = np.concatenate([s.node, c.i, c.j, c.j, c.i])
    ck, ca = _column(nets, "couplings", "k"), _column(nets, "couplings", "a")
    vals = np.concatenate([_column(nets, "springs", "k"), ck / ca, ck * ca, -ck, -ck], axis=1)
    vals = vals * minv[:, rows]
    # sum duplicate (row, col) entries in row-major order (numpy: scipy.sparse's set-up is a
    # noticeable share of a small network's simulation call)
    order = np.argsort(rows * n + cols, kind="stable")
    keys, start = np.unique((rows * n + cols)[order], return_index=True)
    summed = np.add.reduceat(vals[:, order], start, axis=1) if len(rows) else vals
    r, column = np.divmod(keys, n)
    diag = np.zeros((len(vals), n))
    on = r == column
    diag[:, r[on]] = summed[:, on]
    off = ~on
    return diag, np.searchsorted(r[off], np.arange(n + 1)), column[off], -summed[:, off]


class LanesRefused(Exception):
    """Netlists that one kernel call cannot take in its lanes (the reason in words): the
    caller simulates them one call each."""


@dataclass
class Lanes:
    """The runs of several netlists of one structure in one call: run p*reps + r is input r on
    netlist p. `per_run`: the coefficient arrays that differ between the netlists, a column
    per run (entries, runs); `x0`, `v0`: every run's initial state (n, runs)."""

    nets: list[FlatNetlist]
    reps: int
    per_run: dict[str, np.ndarray]
    x0: np.ndarray
    v0: np.ndarray

    def members(self, lo: int, hi: int) -> np.ndarray:
        """The netlist of each run lo..hi-1."""
        return np.arange(lo, hi) // self.reps


# the arrays of `member_arrays` that may differ between the points of one call
PER_RUN_EXTRA = frozenset({"ds_b", "fi_w", "nz_si", "nz_sj"})


def member_arrays(nets: list[FlatNetlist], specs: list[str], rplan,
                  st: Settings) -> dict[str, list[np.ndarray]]:
    """Each netlist's arrays besides the force code's coefficients that the kernel reads:
    the damper rows' coefficients `ds_b` of the dissipation sums, a Lawson kernel's input
    gains `fi_w` of the work sums (only where the sums are asked for: a kernel without them
    does not take them), and the thermal noise's arrays (its dampers' forces over mass
    `nz_si`, `nz_sj` may differ between the points, the rest must not)."""
    out = {}
    if thermal.temperature(nets[0]) > 0:
        noise = [thermal.noise_arrays(n, st.h, np.dtype(st.precision)) for n in nets]
        out.update({key: [a[key] for a in noise] for key in noise[0]})
    if rplan.damper_rows:
        out["ds_b"] = [damper_coefficients(reductions.plan(specs, n), st.precision)
                       for n in nets]
    if rplan.work and expint.is_split(st.method):
        out["fi_w"] = [lawson_gains(n) for n in nets]
    return out


def lane_arrays(nets: list[FlatNetlist], coeffs: dict, st: Settings, reps: int,
                sums: dict[str, list[np.ndarray]]) -> Lanes:
    """The per-run arrays of `nets` (the first's kernel arrays `coeffs`, and each one's
    other arrays `sums`, `member_arrays`): each array equal in every
    netlist stays shared, the others get a column per run. Arrays other than the
    coefficients (an exponential scheme's blocks, the index arrays) must be equal
    (`LanesRefused`)."""
    members = _member_columns([kernel_netlist(n) for n in nets], coeffs, st)
    allowed = codegen.coefficient_names() | PER_RUN_EXTRA | lawson_propagators(coeffs, st)
    per_run = {}
    for key, columns in {**{k: v for k, v in members.items() if k not in sums},
                         **sums}.items():
        stacked = _stacked(columns)
        if stacked is not None and (stacked == stacked[0]).all():
            continue
        if key not in allowed or stacked is None:
            raise LanesRefused(_differs(key, st))
        # the runs last: (entries, runs), a propagator's (blocks, fractions, rows, cols, runs)
        per_run[key] = np.ascontiguousarray(np.repeat(np.moveaxis(stacked, 0, -1), reps, -1))
    x0, v0 = (np.repeat(np.stack(s, 1), reps, 1)
              for s in zip(*(n.initial_state() for n in nets)))
    return Lanes(nets, reps, per_run, x0, v0)


def _member_columns(nets: list[FlatNetlist], coeffs: dict, st: Settings) -> dict:
    """Every kernel array of the kernel netlists `nets` (the first's are `coeffs`), stacked
    over the netlists where it can be: where the scheme is Runge-Kutta and all share one
    kernel pattern, from one `coefficient_columns` (the index arrays, equal by the pattern,
    once); else each netlist's `kernel_arrays` as a list (`LanesRefused` where a Lawson
    kernel's blocks differ in size). `fi_w` is left to `member_arrays`."""
    coeffs = {k: v for k, v in coeffs.items() if k != "fi_w"}
    first = kernel_pattern(nets[0])
    if not expint.is_split(st.method) and all(kernel_pattern(n) == first for n in nets[1:]):
        columns = coefficient_columns(nets[1:], np.dtype(st.precision)) if nets[1:] else {}
        return {key: np.concatenate([value[None], columns[key]]) if columns and
                key in COEFFICIENT_KEYS else value[None] for key, value in coeffs.items()}
    others = [kernel_arrays(n, st, np.dtype(st.precision)) for n in nets[1:]]
    sizes = {k for k in coeffs if k.startswith("lw")}  # a Lawson kernel's block sizes
    if any({k for k in o if k.startswith("lw")} != sizes for o in others):
        raise LanesRefused(_differs("lw", st))
    return {key: [value] + [o[key] for o in others] for key, value in coeffs.items()}


def _stacked(columns: np.ndarray | list[np.ndarray]) -> np.ndarray | None:
    """The arrays of every netlist as one array with a leading axis over them (None where
    their shapes differ)."""
    if isinstance(columns, np.ndarray):
        return columns
    try:
        return np.stack(columns)
    except ValueError:  # shapes differ
        return None


def kernel_arrays(net: FlatNetlist, st: Settings, dtype) -> dict[str, np.ndarray]:
    """Coefficient arrays of the kernel for `st.method` (a split scheme: those of its
    Runge-Kutta part, then its blocks' propagators for the step `st.h`)."""
    if not expint.is_split(st.method):
        return coefficient_arrays(net, dtype)
    blocks = expint.find_blocks(net)
    out = coefficient_arrays(expint.split_netlist(net, blocks), dtype)
    out.update(expint.scheme_arrays(net, blocks, st.h, st.method, dtype))
    out["fi_w"] = lawson_gains(net)
    return out


def lawson_propagators(coeffs: dict, st: Settings) -> set[str]:
    """The arrays of a Lawson kernel's exact blocks that may differ between the runs of one
    call (their propagators, read per lane: `springc.kernels.expint`); none for the other
    schemes."""
    if not expint.is_split(st.method) or expint.SCHEMES[st.method].kind != "lawson":
        return set()
    return {k for k in coeffs if k.startswith("lw") and not k.endswith("_node")}


def _differs(key: str, st: Settings) -> str:
    """Why the points cannot share a call when kernel array `key` differs between them."""
    if key.startswith("nz_"):
        return "thermal noise: the noisy dampers differ between points (b = 0 in some)"
    if expint.is_split(st.method):
        return "the split scheme's exact blocks differ between points"
    return f"the kernel array {key} differs"


def lawson_gains(net: FlatNetlist) -> np.ndarray:
    """The input work of a Lawson kernel: the inputs' own gains (the split zeroes the
    blocks')."""
    return np.ascontiguousarray(net.forces.gain[sources.input_forces(net)], np.float64)


def damper_coefficients(rplan, precision: str) -> np.ndarray:
    """The coefficient of each damper row of the dissipation sums (`ds_b`)."""
    return np.array([r[2] for r in rplan.damper_rows], np.dtype(precision))
