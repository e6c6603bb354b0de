"""The chunk code every generated CPU kernel shares: the divergence guard, the copies of a
chunk's lanes in and out, the last partial record block, the marks of the nodes whose
velocity is read and the restaging of the input samples, compiled once per process (and
cached by numba) instead of in every kernel.

All run rarely (the guard every `check_every` steps, the restaging every STAGE_BLOCK input
samples, the rest once per chunk or call), so a call costs nothing measurable, while
written into each kernel they made its compile 13-22% longer: numba's compile time grows
faster than a function's length
(docs/performance.md#cold-cache-compiles-in-mass-spring-training). A generated kernel
imports them with this module's hash (`codegen.preamble`).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, error_model="numpy")
def guard(x, v, status, bad_node, lo: int, nv: int, limit: float, k1: int) -> int:
    """The divergence guard of a chunk's lanes (x, v: (n, LANES)), runs lo..lo + nv - 1: a
    live lane with NaN/Inf or a state beyond `limit` is marked with the step `k1` and its
    worst node (once). Returns the lanes still alive (0: the chunk can stop)."""
    alive = 0
    for b in range(nv):
        if status[lo + b] != 0:
            continue
        worst = 0.0
        wi = -1
        for i in range(x.shape[0]):
            ax = abs(x[i, b])
            if not (ax <= limit and abs(v[i, b]) <= limit):
                ax = np.inf
            if wi < 0 or ax > worst:
                worst = ax
                wi = i
        if not worst <= limit:
            status[lo + b] = k1
            bad_node[lo + b] = wi
        else:
            alive += 1
    return alive


@nb.njit(cache=True, nogil=True, error_model="numpy")
def store_lanes(out, local, lo: int, nv: int) -> None:
    """out[r, lo + b] = local[r, b] for the chunk's valid lanes b < nv (padding lanes are
    never stored)."""
    for r in range(local.shape[0]):
        for b in range(nv):
            out[r, lo + b] = local[r, b]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def load_lanes(local, src, lo: int, nv: int) -> None:
    """local[r, b] = src[r, lo + b] for every lane of the chunk (local: (rows, LANES)); a
    padding lane (b >= nv) takes the chunk's last run's column."""
    for r in range(local.shape[0]):
        for b in range(local.shape[1]):
            local[r, b] = src[r, lo + min(b, nv - 1)]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def mark_nodes(need, nodes) -> None:
    """need[nodes[e]] = True for every entry (an entry < 0, the ground, marks nothing)."""
    for e in range(nodes.shape[0]):
        if nodes[e] >= 0:
            need[nodes[e]] = True


@nb.njit(cache=True, nogil=True, error_model="numpy")
def record_tail(rec, stg, probes: int, r_hi: int, col: int, nv: int) -> None:
    """The records of a chunk's last, partial staging block (stg: (probes, RB, LANES), r_hi
    the last record staged; ordinary stores) into rec[p, col + b, ...]."""
    rb = stg.shape[1]
    if r_hi >= 0 and r_hi % rb != rb - 1:
        r0 = r_hi - r_hi % rb
        for p in range(probes):
            for b in range(nv):
                for k in range(r_hi % rb + 1):
                    rec[p, col + b, r0 + k] = stg[p, k, b]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def restage(ustg, u, lo: int, nv: int, ubase: int) -> None:
    """The input samples ubase.. of the chunk's runs (u: (runs, channels, samples)) into the
    staging block ustg (samples, channels, LANES), as many as it holds or u has left."""
    top = min(ustg.shape[0], u.shape[2] - ubase)
    for b in range(nv):
        for ch in range(u.shape[1]):
            for t in range(top):
                ustg[t, ch, b] = u[lo + b, ch, ubase + t]
