"""The small reference networks shared by the simulation, check and command tests, with their
helpers: `every_kind` (every force kind, with its inputs and its scipy solution) of
test_written_out, test_regkernel and test_kernels_terms; `nonlinear_net` of test_simulate and
test_reference; the 16 kHz `kicked_pair` of test_checks and test_accuracy; the example netlist
`TWOMODE` of test_accuracy and test_stepcheck; `rel_error` of the integrator tests;
`GRAD_NETLIST` of test_grad_cli and test_points_commands; and `every_kind_netlist`, generated
from the element kinds, of test_grad and test_grad_written."""

from __future__ import annotations

import functools

import numpy as np
from scipy.integrate import solve_ivp

from springc.errors import SourceLoc
from springc.kernels.terms import ELEMENTS
from springc.lang.ir import IRBuilder, Source, Tran

W = 2 * np.pi * 40.0  # rad/s: every node's local frequency scale
H = 1e-4  # s: tstep, about 40 steps per period of the fastest mode
T = 0.05  # s
RUNS = 8  # 4 runs a thread: kernels of 4 lanes (vector code)


def every_kind() -> object:
    """Four masses with every force kind: a, b damped, c undamped, d undamped; springs on
    all; a coupling a-b; quadratic couplings a->c and b->c (c is the second end of two);
    a Duffing term on d; a dashpot b-d; inputs on a (channel 0), b (channel 1) and c
    (channel 0, twice); a sine drive on d."""
    b = IRBuilder("every force kind", "every_kind.spr")
    for name, node, m, damp in (("1", "a", 1.0, 30.0), ("2", "b", 2.0, 10.0),
                                ("3", "c", 0.5, 0.0), ("4", "d", 1.0, 0.0)):
        b.mass(f"M{name}", node, m, damp)
        b.spring(f"K{name}", node, W**2 * m)
    b.coupling("C1", "a", "b", 0.3 * W**2, a=1.5)
    b.quad("Q1", "a", "c", 2e3, a=0.5)
    b.quad("Q2", "b", "c", 1e3, a=2.0)
    b.duffing("D1", "d", 1e7)
    b.dashpot("B1", "b", "d", 5.0)
    b.force("F1", "a", Source("in", channel=0), 1e3)
    b.force("F2", "b", Source("in", channel=1), 2e3)
    b.force("F3", "c", Source("in", channel=0), 5e2)
    b.force("F4", "c", Source("in", channel=0), -2e2)
    b.force("F5", "d", Source("sin", (50.0, 60.0)))
    for node in "abcd":
        b.probe("x", node)
    b.tran = Tran(H, T, None)
    return b.finish()


def inputs(seed: int = 0) -> np.ndarray:
    """(runs, 2 channels, samples) of smooth random signals at 1/H."""
    t = np.arange(int(round(T / H)) + 2) * H
    rng = np.random.default_rng(seed)
    f = rng.uniform(20.0, 120.0, (RUNS, 2, 3))
    return np.sin(2 * np.pi * f[..., None] * t).sum(axis=2) * 1e-3


def scipy_runs(u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Positions of a, b, c, d of every run, (runs, 4, len(t)), from scipy DOP853 on the same
    equations (the input linearly interpolated between samples, as the kernel reads it). The
    runs are one system for scipy (its steps are those of `max_step` for every run alone, so
    each run's solution is the one it gets alone), solved once per module (`_scipy_cached`:
    both forms' tests, and the register kernel's, compare the same runs)."""
    return _scipy_cached(u.tobytes(), u.shape, t.tobytes())


@functools.cache
def _scipy_cached(u_bytes: bytes, shape: tuple, t_bytes: bytes) -> np.ndarray:
    u = np.frombuffer(u_bytes).reshape(shape)
    t = np.frombuffer(t_bytes)
    runs = shape[0]
    grid = np.arange(u.shape[2]) * H
    m = np.array([1.0, 2.0, 0.5, 1.0])[:, None]
    damp = np.array([30.0, 10.0, 0.0, 0.0])[:, None]

    def rhs(time, y):
        x, v = y[:4 * runs].reshape(4, runs), y[4 * runs:].reshape(4, runs)
        u0, u1 = (np.array([np.interp(time, grid, run[ch]) for run in u]) for ch in (0, 1))
        f = -W**2 * m * x - damp * v
        k, a = 0.3 * W**2, 1.5  # k/(2a) (x_a - a x_b)^2
        s = x[0] - a * x[1]
        f[0] -= k / a * s
        f[1] += k * s
        for i, g, aq in ((0, 2e3, 0.5), (1, 1e3, 2.0)):  # g/(2a) (x_i^2 - a x_c)^2
            s = x[i] ** 2 - aq * x[2]
            f[i] -= 2 * g / aq * x[i] * s
            f[2] += g * s
        f[3] -= 1e7 * x[3] ** 3
        fd = 5.0 * (v[1] - v[3])
        f[1] -= fd
        f[3] += fd
        f += np.stack([1e3 * u0, 2e3 * u1, 3e2 * u0,
                       np.full(runs, 50.0 * np.sin(2 * np.pi * 60.0 * time))])
        return np.concatenate([v.ravel(), (f / m).ravel()])

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(8 * runs), method="DOP853", t_eval=t,
                    rtol=1e-11, atol=1e-15, max_step=H / 4)
    return sol.y[:4 * runs].reshape(4, runs, -1).transpose(1, 0, 2)


def assert_matches_scipy(net, u: np.ndarray, res, tol: float = 1e-6) -> None:
    """Every run's positions of a, b, c, d within `tol` (relative L2) of `scipy_runs`."""
    every = scipy_runs(u, res.t)
    for r in range(len(u)):
        want = every[r]
        for k, node in enumerate("abcd"):
            got = res.probes[f"x({node})"][r]
            err = np.linalg.norm(got - want[k]) / np.linalg.norm(want[k])
            assert err < tol, (r, node, err)


def nonlinear_net(in_gain: float = 2.0, sin_gain: float = 0.0):
    """Duffing, quadratic coupling, leverage coupling, dashpots between nodes and to ground,
    a monomial, a sine drive and an input channel."""
    b = IRBuilder("nonlinear network")
    b.mass("M1", "a", 1.0, 3.0)
    b.mass("M2", "c", 2.0, 0.0, x0=0.1)
    b.mass("M3", "d", 0.5, 1.0)
    b.spring("K1", "a", 100.0)
    b.spring("K2", "c", 50.0)
    b.spring("K3", "d", 80.0)
    b.duffing("D1", "a", 1e3)
    b.coupling("C1", "a", "c", 20.0, a=1.5)
    b.quad("Q1", "c", "d", 30.0, a=0.7)
    b.dashpot("B1", "a", "d", 2.0)
    b.dashpot("B2", "c", "0", 0.5)
    b.monomial("P1", 5.0, [("a", 2), ("d", 2)])
    b.force("F1", "a", Source("sin", (5.0, 2.0, 0.3)))
    b.force("F2", "d", Source("in", channel=0), in_gain)
    b.force("F3", "d", Source("sin", (1.0, 5.0)), sin_gain)
    b.probe("x", "a")
    b.probe("v", "d")
    b.probe("x", "c")
    b.tran = Tran(1e-3, 1.0, None)
    return b.finish()


# the split-scheme networks of the checks (springc.kernels.expint)
H16 = 1 / 16000  # a 16 kHz input grid: the top Mel bands sit just below its Nyquist frequency
WS = 2 * np.pi * 50  # the slow part


def net_loc(line: int) -> SourceLoc:
    """Line `line`, column 1 of "net.spr": where the checks' diagnostics point."""
    return SourceLoc("net.spr", line, 1)


def filter_pair(b: IRBuilder, first: str, second: str, w: float, line: int) -> None:
    """A driven two-mode filter pair (paper Eq. filter-response: delta 1.1, alpha 400)."""
    delta, alpha = 1.1, 400.0
    for node, sign in ((first, 1.0), (second, -1.0)):
        b.mass(f"M{node}", node, 1.0, alpha, loc=net_loc(line))
        b.spring(f"K{node}", node, w**2, loc=net_loc(line + 1))
        b.force(f"F{node}", node, Source("in"), alpha * (1 + sign * delta**2) * w**2,
                loc=net_loc(line + 2))
    b.coupling(f"C{first}", first, second, (delta**2 - 1) * w**2 / 2, loc=net_loc(line + 3))


def kicked_pair(kick_hz: float, tstep: float, method: str, tstop: float = 0.05):
    """A 7 kHz filter pair with a slow node r squared onto its node xb (Q r xb): at rest the
    Q puts a stiffness g a on xb that the Runge-Kutta part of a split integrates. (r, s as in
    `test_checks._fast_pairs`, whose kernel this one shares.)"""
    b = IRBuilder(file="net.spr")
    filter_pair(b, "xa", "xb", 2 * np.pi * 7000, 1)
    for node in ("r", "s"):
        b.mass(f"M{node}", node, 1.0, 20.0, loc=net_loc(5))
        b.spring(f"K{node}", node, WS**2, loc=net_loc(6))
    b.coupling("Crs", "r", "s", WS**2 / 4, loc=net_loc(7))
    b.quad("Qrb", "r", "xb", (2 * np.pi * kick_hz) ** 2, loc=net_loc(7))
    b.probe("x", "xb")
    b.tran = Tran(tstep, tstop, net_loc(8))
    b.options["method"] = method
    return b.finish()


# the two-mode filter example, a path relative to the repository root (where the tests run)
TWOMODE = "netlists/examples/twomode_filter.spr"


def rel_error(got: np.ndarray, want: np.ndarray) -> float:
    """The relative L2 error of `got` against `want`."""
    return float(np.linalg.norm(got - want) / np.linalg.norm(want))


# a parametrised two-mass netlist: the `springc grad` tests and their .step/.mc points
GRAD_NETLIST = """\
.param k0=4e5 bb=40 gain=1e5 l0=1e9 unused=3 amp=1
Ma a m=1 b={bb}
Mb b m=1
Ka a k={k0}
Kb b k={2*k0}
Da a l={l0}
Cab a b k=1e5
Fa a in(0) gain={gain}
Fs b sin({amp} 50)
.tran {1/8000} 0.03
"""


def every_kind_netlist(options: str = ".options method=rk4") -> tuple[str, list[str]]:
    """The gradients' network, generated from `terms.ELEMENTS`: a hub mass `h` that every kind
    touches (the two-node kinds once at each end, a grounded end where a kind has one), so
    every pair of kinds meets at a node, and a satellite mass `s0`, `s1`, ... per two-node
    kind; every coefficient a `.param`, the input forces on channel 0. Returns the text and
    the parameters. The integration is pinned (`options`): in a finite-difference test each
    difference is a netlist of its own, whose choice of integration would cost more than its
    simulation."""
    value = {"k": 7.0, "a": 1.3, "l": 2.0, "g": 0.6, "b": 0.2, "gain": 1.5}
    params: dict[str, float] = {}
    lines = ["M1 h m=1 b=0.05 x0=0.3", "K0 h k=9"]
    two = [p for p in ELEMENTS if p.node_j]
    for n, p in enumerate(two):
        lines += [f"Ms{n} s{n} m={1.2 + 0.2 * n} x0={0.1 * (n + 1)} v0=-0.2",
                  f"Ks{n} s{n} k={5 + n}"]
    for k, p in enumerate(ELEMENTS):
        if p.node_j:
            n = two.index(p)
            sites = [f"s{n} h", f"h s{n}"] + ([f"s{n} 0"] if p.ground else [])
        else:
            sites = ["h", f"s{k % len(two)}"]
        for e, site in enumerate(sites):
            keys = []
            for f, _, _ in p.params:  # values apart, so no two coefficients coincide
                params[f"{p.name}{e}_{f}"] = value[f] * (1 + 0.1 * len(params) / 7)
                keys.append(f"{f}={{{p.name}{e}_{f}}}")
            source = " in(0)" if p.channel else " sin(1 1.2 0.5)" if p.signal else ""
            lines.append(f"{p.letter}{p.name}{e} {site}{source} {' '.join(keys)}")
    head = ".param " + " ".join(f"{k}={v!r}" for k, v in params.items())
    return "\n".join([head, *lines, options, ".tran 10ms 0.5", ""]), list(params)
