"""The discrete adjoint of the explicit Runge-Kutta step, in Numba, a chunk of runs per call.

`forward` integrates a chunk of runs in lockstep (state (dofs, lanes), one lane per run)
with the simulator's arithmetic: the same tableau and step h, inputs interpolated linearly at
the stage times, shared sources from the same table. It accumulates the streaming
reductions as the generated kernels do, keeps the state every `every` steps, and leaves the
last segment's stage states in the buffers. `reverse` walks the steps backwards: segment by
segment it recomputes the stage states from the segment's checkpoint (not the last one,
which the forward sweep left), then propagates the adjoint through each step's stages, the
transposed Jacobian of the forces at each stage (`forces_vjp`) and the reductions' seeds.
Memory is O((nsteps / every + every) * stages * dofs * lanes): `every` ~ sqrt(nsteps) keeps it
O(sqrt(nsteps)); `every` = nsteps stores one segment and recomputes nothing.

The forces are plain loops over each term kind's arrays (`springc.grad.model.Model`) with
the lanes innermost, rendered from the element kinds with their transposes
(`springc.grad.render.loop_source`); accelerations are forces times the inverse mass.
Gradients go to the blocks of `model.BLOCKS` (raw coefficients, not over mass), one column
per lane.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from springc.grad.model import B, FC, FI, M, PC, V0, X0

# lanes per chunk: 0 here (read from the arrays); `springc.grad.lanes` compiles a copy of this
# module with it set, so that the lane loops have a constant count (unrolled, vectorised)
LANES = 0
JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
# the per-stage helpers are inlined into the sweeps: a call would take a reference to
# every array of the model (atomic counts) and copy the tuple, at every stage
INLINE = dict(JIT, inline="always")


# `forces` and `forces_vjp`, which call these for the node terms and the monomials, are
# rendered from the element kinds (`springc.grad.render.loop_source`) and appended to this
# module's text by `springc.grad.lanes`.


@njit(**INLINE)
def _own_forces(md, x, v, f):
    """Each node's own damping force, the first term of its sum."""
    for i in range(x.shape[0]):
        for b in range(LANES or x.shape[1]):
            f[i, b] = -md.bn[i] * v[i, b]


@njit(**INLINE)
def _monomial_forces(md, x, f):
    """-c d/dz_k of each monomial on each factor's node."""
    for e in range(md.p_c.shape[0]):
        for k in range(md.p_ptr[e], md.p_ptr[e + 1]):
            for b in range(LANES or x.shape[1]):
                f[md.p_var[k], b] -= md.p_c[e] * _dmono(md.p_ptr, md.p_var, md.p_exp, x, e, k, b)


@njit(**INLINE)
def _dmono(ptr, var, exp, x, e, k, b):
    """d/dz_k of the product of monomial e's factors z_l^e_l (coefficient left out) in lane
    b; each factor counts as its own variable, so a node named twice sums its factors."""
    ek = exp[k]
    if ek == 0:
        return 0.0
    out = ek * x[var[k], b] ** (ek - 1)
    for m in range(ptr[e], ptr[e + 1]):
        if m != k:
            out *= x[var[m], b] ** exp[m]
    return out


@njit(**INLINE)
def _ddmono(ptr, var, exp, x, e, k, m, b):
    """d^2/dz_k dz_m of monomial e's factor product (coefficient left out) in lane b."""
    ek, em = exp[k], exp[m]
    if k == m:
        if ek < 2:
            return 0.0
        out = ek * (ek - 1) * x[var[k], b] ** (ek - 2)
    else:
        if ek == 0 or em == 0:
            return 0.0
        out = ek * em * x[var[k], b] ** (ek - 1) * x[var[m], b] ** (em - 1)
    for q in range(ptr[e], ptr[e + 1]):
        if q != k and q != m:
            out *= x[var[q], b] ** exp[q]
    return out


@njit(**INLINE)
def _own_vjp(md, x, v, fb, vb, gr):
    """The transpose of `_own_forces`."""
    off = md.off
    for i in range(x.shape[0]):
        c = md.bn[i]
        for b in range(LANES or x.shape[1]):
            vb[i, b] -= c * fb[i, b]
            gr[off[B] + i, b] -= v[i, b] * fb[i, b]


@njit(**INLINE)
def _monomials_vjp(md, x, fb, xb, gr):
    """The transpose of `_monomial_forces` (the helper takes arrays, not md: a tuple of
    arrays passed per element is copied)."""
    for e in range(md.p_c.shape[0]):
        _monomial_vjp(md.p_c[e], md.p_ptr, md.p_var, md.p_exp, md.off[PC] + e, x, e, fb, xb,
                      gr)


@njit(**INLINE)
def _monomial_vjp(c, ptr, var, exp, row, x, e, fb, xb, gr):
    """P: the force on each factor's node is -c d/dz_k; its transpose needs the Hessian."""
    for k in range(ptr[e], ptr[e + 1]):
        for b in range(LANES or x.shape[1]):
            gk = -fb[var[k], b]
            gr[row, b] += gk * _dmono(ptr, var, exp, x, e, k, b)
            for m in range(ptr[e], ptr[e + 1]):
                xb[var[m], b] += gk * c * _ddmono(ptr, var, exp, x, e, k, m, b)


@njit(**INLINE)
def _interp(u, step, substeps, c, out):
    """Inputs (channel, sample, lane) at stage time (step + c) h into out (channel, lane):
    linear between input-grid samples, as the kernels interpolate (`codegen.emit_interp`)."""
    k0 = step // substeps
    pos = (step - k0 * substeps + c) / substeps
    ip = int(pos)
    fr = pos - ip
    for ch in range(u.shape[0]):
        for b in range(LANES or u.shape[2]):
            out[ch, b] = (1.0 - fr) * u[ch, k0 + ip, b] + fr * u[ch, k0 + ip + 1, b]


@njit(**INLINE)
def _stages(md, ta, tc, h, x, v, u, gtab, step, substeps, X, V, KV, UC, f):
    """Stage states X, V, accelerations KV and inputs UC (stage, ...) of one step from x, v."""
    n, nl = x.shape[0], LANES or x.shape[1]
    for s in range(tc.shape[0]):
        for i in range(n):
            for b in range(nl):
                X[s, i, b] = x[i, b]
                V[s, i, b] = v[i, b]
        for j in range(s):
            ha = h * ta[s, j]
            if ha != 0.0:
                for i in range(n):
                    for b in range(nl):
                        X[s, i, b] += ha * V[j, i, b]
                        V[s, i, b] += ha * KV[j, i, b]
        _interp(u, step, substeps, tc[s], UC[s])
        forces(md, X[s], V[s], UC[s], gtab[step, s], f)  # noqa: F821 (rendered)
        for i in range(n):
            for b in range(nl):
                KV[s, i, b] = f[i, b] * md.minv[i]


@njit(**INLINE)
def _combine(tb, h, x, v, V, KV):
    """x += h sum_s b_s V_s, v += h sum_s b_s KV_s (in place)."""
    n, nl = x.shape[0], LANES or x.shape[1]
    for i in range(n):
        for b in range(nl):
            dx, dv = 0.0, 0.0
            for s in range(tb.shape[0]):
                dx += h * tb[s] * V[s, i, b]
                dv += h * tb[s] * KV[s, i, b]
            x[i, b] += dx
            v[i, b] += dv


@njit(**INLINE)
def _stage_sums(md, tb, h, step, gtab, V, UC, ds, work, diss):
    """One step's work per force and dissipation per damper row (the tableau's quadrature
    of power, as `codegen.emit_stage_reductions`)."""
    nfi, nl = md.fi_node.shape[0], LANES or V.shape[2]
    for s in range(tb.shape[0]):
        w = h * tb[s]
        for e in range(nfi):
            i, c = md.fi_node[e], w * md.fi_gain[e]
            for b in range(nl):
                work[e, b] += c * UC[s, md.fi_chan[e], b] * V[s, i, b]
        for e in range(md.fc_node.shape[0]):
            i, c = md.fc_node[e], w * md.fc_gain[e] * gtab[step, s, e]
            for b in range(nl):
                work[nfi + e, b] += c * V[s, i, b]
        for d in range(ds.shape[0]):
            i, j, c = int(ds[d, 0]), int(ds[d, 1]), w * ds[d, 2]
            for b in range(nl):
                dv = V[s, i, b] - (V[s, j, b] if j >= 0 else 0.0)
                diss[d, b] += c * dv * dv


@njit(**INLINE)
def _state_sums(k, x, v, ms, msq, gp, gdecay, gram):
    """Reductions of the state after step k: windowed squares (ms rows node, isv, lo, hi)
    and the leaky Gram sums (gp rows i, j, group, weight times h)."""
    nl = LANES or x.shape[1]
    for r in range(ms.shape[0]):
        if ms[r, 2] <= k <= ms[r, 3]:
            q = v[ms[r, 0]] if ms[r, 1] else x[ms[r, 0]]
            for b in range(nl):
                msq[r, b] += q[b] * q[b]
    if k > 0:
        for g in range(gram.shape[0]):
            for b in range(nl):
                gram[g, b] *= gdecay[g]
    for p in range(gp.shape[0]):
        i, j, g, w = int(gp[p, 0]), int(gp[p, 1]), int(gp[p, 2]), gp[p, 3]
        for b in range(nl):
            gram[g, b] += w * x[i, b] * x[j, b]


@njit(**JIT)
def forward(md, ta, tb, tc, h, nsteps, substeps, x, v, u, gtab, every, cps, X, V, KV, UC,
            ds, ms, gp, gdecay, work, diss, msq, gram):
    """Integrate a chunk of runs from x, v (dofs, lanes; the final state on return) for
    nsteps steps; store the state before every `every`-th step in cps (checkpoint, 2, dofs,
    lanes), the last segment's stages in X, V, KV, UC (step in segment, stage, ...) and the
    reductions in work, diss, msq, gram (row, lane)."""
    f = np.zeros(x.shape)
    last = (nsteps - 1) // every
    _state_sums(0, x, v, ms, msq, gp, gdecay, gram)
    for step in range(nsteps):
        seg, t = step // every, step % every
        if t == 0:
            cps[seg, 0] = x
            cps[seg, 1] = v
        q = t if seg == last else 0  # earlier segments: scratch in the first slot
        _stages(md, ta, tc, h, x, v, u, gtab, step, substeps, X[q], V[q], KV[q], UC[q], f)
        _stage_sums(md, tb, h, step, gtab, V[q], UC[q], ds, work, diss)
        _combine(tb, h, x, v, V[q], KV[q])
        _state_sums(step + 1, x, v, ms, msq, gp, gdecay, gram)


@njit(**INLINE)
def _state_seeds(k, x, v, xb, vb, ms, msw, gp, gw, fac, gdecay):
    """Add the reductions' adjoints at the state after step k (msw per ms row, gw per Gram
    pair: d result / d sum), then age the Gram factors by one step."""
    nl = LANES or x.shape[1]
    for r in range(ms.shape[0]):
        if ms[r, 2] <= k <= ms[r, 3]:
            node = ms[r, 0]
            for b in range(nl):
                if ms[r, 1]:
                    vb[node, b] += 2.0 * msw[r, b] * v[node, b]
                else:
                    xb[node, b] += 2.0 * msw[r, b] * x[node, b]
    for p in range(gp.shape[0]):
        i, j = int(gp[p, 0]), int(gp[p, 1])
        for b in range(nl):
            w = gw[p, b] * gp[p, 3] * fac[p]
            xb[i, b] += w * x[j, b]
            xb[j, b] += w * x[i, b]
        fac[p] *= gdecay[int(gp[p, 2])]


@njit(**INLINE)
def _stage_seeds(md, tb, h, step, gtab, V, UC, ds, ww, dw, VB, gr, dgr):
    """The work and dissipation sums' adjoints (ww per force, dw per damper row) at the stage
    velocities (into VB) and at the gains and damper coefficients (into gr, dgr)."""
    nfi, nl = md.fi_node.shape[0], LANES or V.shape[2]
    for s in range(tb.shape[0]):
        w = h * tb[s]
        for e in range(nfi):
            i, ch, c = md.fi_node[e], md.fi_chan[e], w * md.fi_gain[e]
            for b in range(nl):
                VB[s, i, b] += ww[e, b] * c * UC[s, ch, b]
                gr[md.off[FI] + e, b] += ww[e, b] * w * UC[s, ch, b] * V[s, i, b]
        for e in range(md.fc_node.shape[0]):
            i, g = md.fc_node[e], w * gtab[step, s, e]
            for b in range(nl):
                VB[s, i, b] += ww[nfi + e, b] * g * md.fc_gain[e]
                gr[md.off[FC] + e, b] += ww[nfi + e, b] * g * V[s, i, b]
        for d in range(ds.shape[0]):
            i, j, c = int(ds[d, 0]), int(ds[d, 1]), w * ds[d, 2]
            for b in range(nl):
                dv = V[s, i, b] - (V[s, j, b] if j >= 0 else 0.0)
                VB[s, i, b] += 2.0 * dw[d, b] * c * dv
                if j >= 0:
                    VB[s, j, b] -= 2.0 * dw[d, b] * c * dv
                dgr[d, b] += dw[d, b] * w * dv * dv


@njit(**INLINE)
def _step_vjp(md, ta, tb, h, step, gtab, X, V, KV, UC, xb, vb, VB, KB, XB, fb, gr):
    """Turn xb, vb (adjoint of the state after the step) into the adjoint of the state
    before it, through the stages in reverse; VB holds the stage velocities' reduction
    adjoints on entry."""
    S, n, nl = tb.shape[0], xb.shape[0], LANES or xb.shape[1]
    for s in range(S):
        w = h * tb[s]
        for i in range(n):
            for b in range(nl):
                VB[s, i, b] += w * xb[i, b]
                KB[s, i, b] = w * vb[i, b]
    for s in range(S - 1, -1, -1):
        for i in range(n):
            mi = md.minv[i]
            for b in range(nl):
                fb[i, b] = KB[s, i, b] * mi
                gr[md.off[M] + i, b] -= KB[s, i, b] * KV[s, i, b] * mi
                XB[i, b] = 0.0
        forces_vjp(md, X[s], V[s], UC[s], gtab[step, s], fb, XB, VB[s], gr)  # noqa: F821
        for i in range(n):
            for b in range(nl):
                xb[i, b] += XB[i, b]
                vb[i, b] += VB[s, i, b]
        for j in range(s):
            ha = h * ta[s, j]
            if ha != 0.0:
                for i in range(n):
                    for b in range(nl):
                        VB[j, i, b] += ha * XB[i, b]
                        KB[j, i, b] += ha * VB[s, i, b]


@njit(**JIT)
def reverse(md, ta, tb, tc, h, nsteps, substeps, u, gtab, every, cps, X, V, KV, UC, xf, vf,
            ds, ms, gp, gdecay, ww, dw, msw, gw, xb, vb, gr, dgr):
    """The adjoint sweep of a chunk after its `forward`: xb, vb hold the adjoint of the final
    state xf, vf on entry and of the initial state on return; the coefficient gradient is
    added into gr (the damper rows' own coefficients into dgr). The seeds: ww per force, dw
    per damper row, msw per ms row, gw per Gram pair (row, lane)."""
    n, nl = xf.shape[0], LANES or xf.shape[1]
    S = tc.shape[0]
    SX, SV = np.zeros((every + 1, n, nl)), np.zeros((every + 1, n, nl))
    VB, KB = np.zeros((S, n, nl)), np.zeros((S, n, nl))
    XB, fb, f = np.zeros((n, nl)), np.zeros((n, nl)), np.zeros((n, nl))
    fac = np.ones(gp.shape[0])
    _state_seeds(nsteps, xf, vf, xb, vb, ms, msw, gp, gw, fac, gdecay)
    last = (nsteps - 1) // every
    for seg in range(last, -1, -1):
        start = seg * every
        count = min(nsteps, start + every) - start
        SX[0], SV[0] = cps[seg, 0], cps[seg, 1]
        for t in range(count):
            SX[t + 1], SV[t + 1] = SX[t], SV[t]
            if seg != last:  # the forward sweep left the last segment's stages
                _stages(md, ta, tc, h, SX[t + 1], SV[t + 1], u, gtab, start + t, substeps,
                        X[t], V[t], KV[t], UC[t], f)
            _combine(tb, h, SX[t + 1], SV[t + 1], V[t], KV[t])
        for t in range(count - 1, -1, -1):
            step = start + t
            VB[:] = 0.0
            _stage_seeds(md, tb, h, step, gtab, V[t], UC[t], ds, ww, dw, VB, gr, dgr)
            _step_vjp(md, ta, tb, h, step, gtab, X[t], V[t], KV[t], UC[t], xb, vb, VB, KB,
                      XB, fb, gr)
            _state_seeds(step, SX[t], SV[t], xb, vb, ms, msw, gp, gw, fac, gdecay)
    for i in range(n):
        for b in range(nl):
            gr[md.off[X0] + i, b] += xb[i, b]
            gr[md.off[V0] + i, b] += vb[i, b]
