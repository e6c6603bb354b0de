"""Thermal noise forces in the generated kernels, as text (`springc.sim.thermal` prepares
their arrays; `.options temp=`).

Every damper e (an `M ... b=` to ground, then a `B` dashpot: the order of
`springc.analyses.noise.dissipative`) draws one standard normal z per run and integration
step, held over the step: its force is sigma_e z on node i and -sigma_e z on node j, with
sigma_e = sqrt(2 k_B T b_e / h) (one-sided PSD 4 k_B T b_e up to the step's Nyquist
frequency). The draw is counter-based: z is a function of (seed, global run index, e, step)
only, so a run's noise does not depend on the batch, the chunk, the lane, the thread or the
kernel form. Dampers are drawn in pairs p = e // 2: SplitMix64's finalizer `mix` makes the
stream key key = mix(mix(mix(seed + G) + run) + p) and the step's 64 bits
mix(key + (step + 1) G), whose halves are a uniform u1 in (0, 1) and an angle; Box-Muller
makes two independent normals of them, sqrt(-2 ln u1) times the angle's cosine for the even
damper and its sine for the odd one (a pair shares the logarithm, square root and
sine-cosine pair), in arithmetic of their own that the lane loops vectorise (`normals`).

In a kernel (`emit_chunk_init`, `emit_draw` once per step, `emit_add` after every stage's
force code) the draws go into rows `nz` (node, lane) of accelerations (force over mass),
which every stage adds to its own. `normals` is the same generator in numpy, for tests.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import math
from pathlib import Path

import numpy as np

# the runtime arguments of a kernel with thermal noise (`springc.sim.thermal.noise_arrays`):
# noisy nodes, each damper's nodes (j < 0: the ground) and sigma over each end's mass, the
# seed, and the global index of the call's first run
NOISE_ARGS = ("nz_node", "nz_i", "nz_j", "nz_si", "nz_sj", "nz_seed", "run0")

GAMMA = 0x9E3779B97F4A7C15  # SplitMix64's increment (the golden ratio in 64 bits)
MIX1 = 0xBF58476D1CE4E5B9
MIX2 = 0x94D049BB133111EB
# Box-Muller in arithmetic that vectorises over lanes (`normals` says how)
FRAC = 2**30 - 1  # the angle's 30 bits within a quarter turn
HALF_FRAC = 2.0**29 - 0.5  # their midpoint
QUARTER_STEP = (np.pi / 2) * 2.0**-30  # radians per unit of them
LOG_BIAS = 31.0  # u1 = x 2^(31 - lz) (`normals`)
LN2 = 0.6931471805599453
SQRT_HALF = 0.7071067811865476
LOG_COEFFS = tuple(1.0 / (2 * k + 1) for k in range(9))  # atanh(s) / s in s^2, to s^16
SIN_COEFFS = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(8))  # to a^15
COS_COEFFS = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(8))  # to a^14


def emit_helpers(c, decorator: str) -> None:
    """The generator's functions at module level of a kernel (`decorator`: the njit line).
    Every integer operand is uint64: numba makes float64 of uint64 mixed with int64."""
    c(f"from springc.kernels.vmath import clz, sqrt_  # {_vmath_hash()}")
    c("")
    c(f"NZ_GAMMA = np.uint64({GAMMA:#x})")
    c(f"NZ_MIX1 = np.uint64({MIX1:#x})")
    c(f"NZ_MIX2 = np.uint64({MIX2:#x})")
    c("NZ_LOW = np.uint64(0xFFFFFFFF)")
    c(f"NZ_FRAC = np.uint64({FRAC:#x})")
    for s in (1, 2, 27, 30, 31, 32):
        c(f"NZ_S{s} = np.uint64({s})")
    for name, values in (("NZ_LOG", LOG_COEFFS), ("NZ_SIN", SIN_COEFFS),
                         ("NZ_COS", COS_COEFFS)):
        for k, v in enumerate(values):
            c(f"{name}{k} = {v!r}")
    # inlined by numba itself, so that the kernels' lane loops see (and vectorise) the code
    assert decorator.startswith("@nb.njit("), decorator
    inline = decorator.replace("@nb.njit(", '@nb.njit(inline="always", ', 1)
    c("")
    c("")
    c(inline)
    c("def nz_mix(z):")
    c("    z = (z ^ (z >> NZ_S30)) * NZ_MIX1")
    c("    z = (z ^ (z >> NZ_S27)) * NZ_MIX2")
    c("    return z ^ (z >> NZ_S31)")
    c("")
    c("")
    c(decorator)
    c("def nz_key(seed, run, p):")
    c('    """The stream key of damper pair p in run `run` (uint64 each)."""')
    c("    return nz_mix(nz_mix(nz_mix(seed + NZ_GAMMA) + run) + p)")
    c("")
    c("")
    c(inline)
    c("def nz_normals(state):")
    c('    """Two standard normals from the counter state key + (step + 1) G (Box-Muller in')
    c('    branch-free arithmetic: see `springc.kernels.thermal.normals`)."""')
    c("    r = nz_mix(state)")
    c("    k = ((r >> NZ_S32) << NZ_S1) | NZ_S1")
    c("    lz = clz(k)")
    c(f"    x = np.float64(k << lz) * {2.0**-64!r}")
    c(f"    e = {LOG_BIAS!r} - np.float64(lz)")
    c(f"    if x < {SQRT_HALF!r}:")
    c("        x = 2.0 * x")
    c("        e = e - 1.0")
    c("    s = (x - 1.0) / (x + 1.0)")
    c("    z = s * s")
    c(f"    p = {horner('z', 'NZ_LOG', len(LOG_COEFFS))}")
    c(f"    rad = sqrt_(-2.0 * (2.0 * s * p + e * {LN2!r}))")
    c("    lo = r & NZ_LOW")
    c(f"    a = (np.float64(lo & NZ_FRAC) - {HALF_FRAC!r}) * {QUARTER_STEP!r}")
    c("    a2 = a * a")
    c(f"    sa = a * ({horner('a2', 'NZ_SIN', len(SIN_COEFFS))})")
    c(f"    ca = {horner('a2', 'NZ_COS', len(COS_COEFFS))}")
    c("    q = lo >> NZ_S30")
    c("    if q & NZ_S1:  # a quarter turn: (cos, sin) -> (-sin, cos)")
    c("        ca, sa = -sa, ca")
    c("    if q & NZ_S2:  # a half turn")
    c("        ca, sa = -ca, -sa")
    c("    return rad * ca, rad * sa")
    c("")


@functools.cache
def _vmath_hash() -> str:
    """A hash of `springc.kernels.vmath`'s source, written into the kernels that import it
    (numba's cache checks only a kernel's own file). Read, not imported: no numba here."""
    origin = importlib.util.find_spec("springc.kernels.vmath").origin
    return hashlib.sha256(Path(origin).read_bytes()).hexdigest()[:16]


def horner(var: str, name: str, count: int) -> str:
    """The polynomial sum_k {name}{k} var^k as nested multiply-adds, text."""
    text = f"{name}{count - 1}"
    for k in range(count - 2, -1, -1):
        text = f"{name}{k} + {var} * ({text})"
    return text


def emit_chunk_init(c) -> None:
    """At a chunk's start (`lo_`, `n`, LANES defined): each damper pair's stream key per
    lane (padding lanes get keys of runs beyond the call's, never stored), the pair's two
    normals `nzz` and the rows `nz`."""
    c("nzk = np.empty(((nz_i.shape[0] + 1) // 2, LANES), np.uint64)")
    c("for p_ in range(nzk.shape[0]):")
    c("    for b in range(LANES):")
    c("        nzk[p_, b] = nz_key(nz_seed, np.uint64(run0 + lo_ + b), np.uint64(p_))")
    c("nzz = np.zeros((2, LANES))")
    c("nz = np.zeros((n, LANES), FT)")


def emit_draw(c, per_run: tuple[str, ...] = ()) -> None:
    """At a step's start (`step` the step index): the noisy rows of `nz` from this step's
    draws, every damper adding to its node i and subtracting from its node j. `per_run`:
    the kernel's arrays with a column per run (the points of `.step`/`.mc` in its lanes);
    `nz_si`, `nz_sj` there are read per lane."""
    lane_si, lane_sj = "nz_si" in per_run, "nz_sj" in per_run
    si = "nz_si_l[e, b]" if lane_si else "si"
    sj = "nz_sj_l[e, b]" if lane_sj else "sj"
    c("for k_ in range(nz_node.shape[0]):")
    c("    q_ = nz_node[k_]")
    c("    for b in range(LANES):")
    c("        nz[q_, b] = 0.0")
    c("nzc = np.uint64(step + 1) * NZ_GAMMA")
    c("for p_ in range(nzk.shape[0]):")
    c.indent()
    c("for b in range(LANES):")
    c("    nzz[0, b], nzz[1, b] = nz_normals(nzk[p_, b] + nzc)")
    c("for e in range(2 * p_, min(2 * p_ + 2, nz_i.shape[0])):")
    c.indent()
    c("i = nz_i[e]")
    c("j = nz_j[e]")
    if not lane_si:
        c("si = nz_si[e]")
    c("h_ = e - 2 * p_")
    c("if j < 0:  # to ground")
    c("    for b in range(LANES):")
    c(f"        nz[i, b] += {si} * FT(nzz[h_, b])")
    c("else:")
    if not lane_sj:
        c("    sj = nz_sj[e]")
    c("    for b in range(LANES):")
    c("        zf = FT(nzz[h_, b])")
    c(f"        nz[i, b] += {si} * zf")
    c(f"        nz[j, b] -= {sj} * zf")
    c.dedent(2)


def emit_add(c, target: str = "ka") -> None:
    """After a stage's force code: the step's noise added to the noisy rows of `target`."""
    c("for k_ in range(nz_node.shape[0]):")
    c("    q_ = nz_node[k_]")
    c("    for b in range(LANES):")
    c(f"        {target}[q_, b] += nz[q_, b]")


def mix(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finalizer on uint64 values (wrapping)."""
    z = np.asarray(z, np.uint64)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(MIX1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(MIX2)
    return z ^ (z >> np.uint64(31))


def normals(seed: int, runs, elements, steps) -> np.ndarray:
    """The kernels' standard normals for every (run, element, step) of the given index
    arrays, shape (runs, elements, steps).

    Box-Muller on the 64 bits r = mix(key + (step + 1) G): the high 32 bits h give
    u1 = (2 h + 1) 2^-33 in (0, 1), the low 32 an angle on 2^32 points of the circle.
    ln u1 = ln x + e ln 2, with x = (2 h + 1) 2^lz 2^-64 in [0.5, 1) (lz the leading zeros
    of 2 h + 1 in 64 bits, an integer shift, exact) moved to [sqrt(1/2), sqrt(2)), and ln x =
    2 atanh(s), s = (x - 1) / (x + 1), by its series to s^17 (|s| < 0.172: error < 1e-15).
    The angle is a quarter turn q (the top 2 bits) plus a in (-pi/4, pi/4) (the other 30),
    whose sine and cosine are Taylor polynomials to a^15 and a^14 (error < 1e-15); the
    quarter turns swap and negate them. No libm call and no branch: the kernels' lane loops
    vectorise it (libm's log and sincos, per lane, cost as much as the network's forces)."""
    elements = np.asarray(elements, np.int64)
    odd = (elements % 2 == 1)[None, :, None]
    return box_muller(counter_bits(seed, runs, elements, steps), odd)


def counter_bits(seed: int, runs, elements, steps) -> np.ndarray:
    """The 64 bits r of every (run, element, step), uint64 of shape (runs, elements, steps);
    the two dampers of a pair share them."""
    u = np.uint64
    with np.errstate(over="ignore"):
        base = mix(u(seed) + u(GAMMA))
        run = np.asarray(runs, u)[:, None, None]
        pair = (np.asarray(elements, np.int64) // 2).astype(u)[None, :, None]
        key = mix(mix(base + run) + pair)
        state = key + (np.asarray(steps, u)[None, None, :] + u(1)) * u(GAMMA)
        return mix(state)


def box_muller(r: np.ndarray, odd) -> np.ndarray:
    """The kernels' normal of the bits `r`: the cosine branch, or the sine one where `odd`."""
    u = np.uint64
    k = ((r >> u(32)) << u(1)) | u(1)
    bits = np.frexp(k.astype(np.float64))[1]  # exact: k < 2^33
    lz = (64 - bits).astype(u)
    x = (k << lz).astype(np.float64) * 2.0**-64
    e = LOG_BIAS - lz.astype(np.float64)
    low = x < SQRT_HALF
    x = np.where(low, 2.0 * x, x)
    e = np.where(low, e - 1.0, e)
    s = (x - 1.0) / (x + 1.0)
    rad = np.sqrt(-2.0 * (2.0 * s * _horner(s * s, LOG_COEFFS) + e * LN2))
    lo = r & u(0xFFFFFFFF)
    a = ((lo & u(FRAC)).astype(np.float64) - HALF_FRAC) * QUARTER_STEP
    sa = a * _horner(a * a, SIN_COEFFS)
    ca = _horner(a * a, COS_COEFFS)
    q = lo >> u(30)
    turn = (q & u(1)) != 0
    ca, sa = np.where(turn, -sa, ca), np.where(turn, ca, sa)
    half = (q & u(2)) != 0
    ca, sa = np.where(half, -ca, ca), np.where(half, -sa, sa)
    return rad * np.where(odd, sa, ca)


def box_muller_libm(r: np.ndarray, odd) -> np.ndarray:
    """`box_muller` with numpy's logarithm, sine and cosine on the same u1 and angle: the
    transform that the kernels' polynomials approximate (for checks)."""
    u = np.uint64
    u1 = ((r >> u(32)).astype(np.float64) * 2.0 + 1.0) * 2.0**-33
    lo = r & u(0xFFFFFFFF)
    angle = ((lo >> u(30)).astype(np.float64) * (np.pi / 2)
             + ((lo & u(FRAC)).astype(np.float64) - HALF_FRAC) * QUARTER_STEP)
    return np.sqrt(-2.0 * np.log(u1)) * np.where(odd, np.sin(angle), np.cos(angle))


def _horner(z: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    """sum_k coeffs[k] z^k, as the kernels' `horner` text evaluates it."""
    p = np.full_like(z, coeffs[-1])
    for c in coeffs[-2::-1]:
        p = c + z * p
    return p
