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
mix(key + (step + 1) G), whose halves are two uniforms in (0, 1); Box-Muller makes two
independent normals of them, sqrt(-2 ln u1) cos(2 pi u2) for the even damper and the sine
for the odd one (the logarithm, square root and sine-cosine pair are most of the noise's
cost, so a pair shares them).

In a kernel (`emit_chunk_init`, `emit_draw` once per step, `emit_add` after every stage's
force code) the draws go into rows `nz` (node, lane) of accelerations (force over mass),
which every stage adds to its own. `normals` is the same generator in numpy, for tests.
"""

from __future__ import annotations

import numpy as np

# the runtime arguments of a kernel with thermal noise (`springc.sim.thermal.noise_arrays`):
# noisy nodes, each damper's nodes (j < 0: the ground) and sigma over each end's mass, the
# seed, and the global index of the call's first run
NOISE_ARGS = ("nz_node", "nz_i", "nz_j", "nz_si", "nz_sj", "nz_seed", "run0")

GAMMA = 0x9E3779B97F4A7C15  # SplitMix64's increment (the golden ratio in 64 bits)
MIX1 = 0xBF58476D1CE4E5B9
MIX2 = 0x94D049BB133111EB
TWO_PI = 6.283185307179586


def emit_helpers(c, decorator: str) -> None:
    """The generator's functions at module level of a kernel (`decorator`: the njit line).
    Every operand is uint64: numba makes float64 of uint64 mixed with int64."""
    c(f"NZ_GAMMA = np.uint64({GAMMA:#x})")
    c(f"NZ_MIX1 = np.uint64({MIX1:#x})")
    c(f"NZ_MIX2 = np.uint64({MIX2:#x})")
    c("NZ_LOW = np.uint64(0xFFFFFFFF)")
    for s in (27, 30, 31, 32):
        c(f"NZ_S{s} = np.uint64({s})")
    c("")
    c("")
    c(decorator)
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
    c(decorator)
    c("def nz_normals(state):")
    c('    """Two standard normals from the counter state key + (step + 1) G (Box-Muller)."""')
    c("    r = nz_mix(state)")
    c("    u1 = (np.float64(r >> NZ_S32) + 0.5) * 2.3283064365386963e-10")
    c(f"    a = {TWO_PI!r} * ((np.float64(r & NZ_LOW) + 0.5) * 2.3283064365386963e-10)")
    c("    rad = np.sqrt(-2.0 * np.log(u1))")
    c("    return rad * np.cos(a), rad * np.sin(a)")
    c("")


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


def emit_draw(c) -> None:
    """At a step's start (`step` the step index): the noisy rows of `nz` from this step's
    draws, every damper adding to its node i and subtracting from its node j."""
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
    c("si = nz_si[e]")
    c("h_ = e - 2 * p_")
    c("if j < 0:  # to ground")
    c("    for b in range(LANES):")
    c("        nz[i, b] += si * FT(nzz[h_, b])")
    c("else:")
    c("    sj = nz_sj[e]")
    c("    for b in range(LANES):")
    c("        zf = FT(nzz[h_, b])")
    c("        nz[i, b] += si * zf")
    c("        nz[j, b] -= sj * zf")
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
    arrays, shape (runs, elements, steps)."""
    u = np.uint64
    elements = np.asarray(elements, np.int64)
    with np.errstate(over="ignore"):
        base = mix(u(seed) + u(GAMMA))
        run = np.asarray(runs, u)[:, None, None]
        pair = (elements // 2).astype(u)[None, :, None]
        key = mix(mix(base + run) + pair)
        state = key + (np.asarray(steps, u)[None, None, :] + u(1)) * u(GAMMA)
        r = mix(state)
    u1 = ((r >> u(32)).astype(np.float64) + 0.5) * 2.0**-32
    angle = TWO_PI * (((r & u(0xFFFFFFFF)).astype(np.float64) + 0.5) * 2.0**-32)
    odd = (elements % 2 == 1)[None, :, None]
    return np.sqrt(-2.0 * np.log(u1)) * np.where(odd, np.sin(angle), np.cos(angle))
