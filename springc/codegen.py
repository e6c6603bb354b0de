"""Code generation: from a flat netlist to the Python source of a Numba kernel, as plain text.

The kernel is specialised to the element kinds the netlist uses (a netlist without `Q` gets no
`Q` loop), to the integrator (stages unrolled from the Butcher tableau), the precision and the
recorded quantities. Node indices and coefficients are *runtime arguments*, so changing a
parameter value reuses the compiled kernel. The state is laid out `(n_dof, batch)` with the
batch as the innermost, SIMD-friendly loop; `run` integrates a range of chunks of runs and
releases the GIL, so the runtime runs chunks on several threads.

This module never imports numba: `springc.loader` compiles the text.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import asdict, dataclass

from springc.integrators import Tableau, get_tableau
from springc.ir import FlatNetlist

KERNEL_VERSION = 1  # bump when the generated text or its calling convention changes


@dataclass(frozen=True)
class KernelOptions:
    """Everything besides the element kinds that changes the generated text.

    `record`: store probe trajectories; `work`: accumulate input work per force element;
    `dissipation`: accumulate energy dissipated in dampers; `msq`: windowed mean squares;
    `gram`: leaky Gram sums of node-pair products (springc.reductions `gram`)."""

    method: str = "rk4"
    precision: str = "float64"
    record: bool = True
    work: bool = False
    dissipation: bool = False
    msq: bool = False
    gram: bool = False


@dataclass(frozen=True)
class Features:
    """Which element kinds and force kinds the netlist uses."""

    local_damping: bool
    springs: bool
    duffings: bool
    couplings: bool
    quads: bool
    dashpots: bool
    monomials: bool
    in_forces: bool
    common_forces: bool


def features(net: FlatNetlist) -> Features:
    """The element kinds present in `net` (the part of the netlist that shapes the kernel)."""
    kinds = [s.kind for s in net.forces.source]
    return Features(
        # always on: one multiply per node, and damped/undamped variants share one kernel
        local_damping=True,
        springs=len(net.springs) > 0,
        duffings=len(net.duffings) > 0,
        couplings=len(net.couplings) > 0,
        quads=len(net.quads) > 0,
        dashpots=len(net.dashpots) > 0,
        monomials=len(net.monomials) > 0,
        in_forces=any(k == "in" for k in kinds),
        common_forces=any(k != "in" for k in kinds),
    )


# Runtime arguments of `accel`, per feature (coefficients prepared by springc.simulate).
_ACCEL_ARGS = {
    "local_damping": ("bloc",),
    "springs": ("k_node", "k_k"),
    "duffings": ("d_node", "d_l"),
    "couplings": ("c_i", "c_j", "c_k", "c_ka"),
    "quads": ("q_i", "q_j", "q_g", "q_a", "q_g2a"),
    "dashpots": ("b_i", "b_j", "b_b"),
    "monomials": ("p_c", "p_ptr", "p_var", "p_exp"),
    "in_forces": ("fi_node", "fi_gain", "fi_chan"),
    "common_forces": ("fc_node", "fc_gain"),
}


def accel_args(feat: Features) -> list[str]:
    """Names of the coefficient arrays the kernel takes for these features, in order."""
    names = ["minv"]
    for key, args in _ACCEL_ARGS.items():
        if getattr(feat, key):
            names += args
    return names


def run_args(feat: Features, opts: KernelOptions) -> list[str]:
    """Names of all arguments of the generated `run`, in order."""
    names = ["x0", "v0", "u", "g", "nsteps", "substeps", "h", "chunk", "c0", "c1",
             "check_every", "limit"]
    names += accel_args(feat)
    if opts.record:
        names += ["rec_every", "rec_node", "rec_isv", "rec"]
    if opts.work:
        names += ["work_in", "work_c"]
    if opts.dissipation:
        names += ["ds_i", "ds_j", "ds_b", "diss"]
    if opts.msq:
        names += ["ms_node", "ms_isv", "ms_lo", "ms_hi", "msq"]
    if opts.gram:
        names += ["gr_i", "gr_j", "gr_g", "gr_w", "gr_decay", "gram"]
    names += ["xf", "vf", "status", "bad_node"]
    return names


def generate(net: FlatNetlist, options: KernelOptions) -> str:
    """Python source of the kernel for `net` under `options`, with a descriptive header."""
    feat = features(net)
    tab = get_tableau(options.method)
    body = _body(feat, options, tab)
    digest = source_hash(body)
    header = [
        "# springc generated kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {net.file}",
        f"# title: {net.title}",
        f"# options: {asdict(options)}",
        f"# integrator: {tab.name} ({tab.description})",
        f"# dofs: {net.n}; elements: {net.element_counts()}",
        f"# body-hash: {digest}",
        "",
    ]
    return "\n".join(header) + body


def source_hash(text: str) -> str:
    """Short content hash naming the kernel file (same text -> same compiled cache)."""
    return hashlib.sha256(f"{KERNEL_VERSION}\n{text}".encode()).hexdigest()[:20]


_PER_NETLIST = ("# netlist: ", "# title: ", "# dofs: ")


def shared_text(source: str) -> str:
    """The source without the header lines that name one netlist: what the cache stores, so
    every netlist with the same element kinds and options shares one compiled kernel (and a
    cached file is never rewritten with another header, which would invalidate numba's
    cache)."""
    return "".join(line for line in source.splitlines(keepends=True)
                   if not line.startswith(_PER_NETLIST))


def kernel_hash(source: str) -> str:
    """The hash naming a kernel's cache file (of `shared_text`)."""
    return source_hash(shared_text(source))


class _Code:
    """A tiny indented-line writer."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.level = 0

    def __call__(self, text: str = "") -> None:
        self.lines.append("    " * self.level + text if text else "")

    def indent(self, by: int = 1) -> None:
        self.level += by

    def dedent(self, by: int = 1) -> None:
        self.level -= by

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def _body(feat: Features, opts: KernelOptions, tab: Tableau) -> str:
    c = _Code()
    c('"""Generated by springc.codegen; see the header. Arrays are (n_dof, batch)."""')
    c("import numpy as np")
    c("import numba as nb")
    c("")
    c(f"FT = np.{opts.precision}")
    c(f"ARGS = {tuple(run_args(feat, opts))!r}")
    c(f"STAGES = {tab.stages}")
    c("CHUNK_RANGE = True  # run(c0, c1) integrates only chunks c0..c1-1: callers use threads")
    c("")
    _emit_accel(c, feat)
    c("")
    _emit_run(c, feat, opts, tab)
    return c.text()


def _loop_b(c: _Code, stmt: list[str]) -> None:
    c("for b in range(nb_):")
    c.indent()
    for s in stmt:
        c(s)
    c.dedent()


def _emit_accel(c: _Code, feat: Features) -> None:
    args = ["x", "v", "out", "uc", "grow"] + accel_args(feat)
    c('@nb.njit(cache=True, error_model="numpy", nogil=True)')
    c(f"def accel({', '.join(args)}):")
    c.indent()
    c('"""out = M^-1 (F_internal + F_damping + F_external) for one stage, all runs in x."""')
    c("n, nb_ = x.shape")
    c("for i in range(n):")
    c.indent()
    if feat.local_damping:
        c("bi = bloc[i]")
        _loop_b(c, ["out[i, b] = -bi * v[i, b]"])
    else:
        _loop_b(c, ["out[i, b] = 0.0"])
    c.dedent()
    if feat.springs:
        _element_loop(c, "k_node", ["i = k_node[e]", "k = k_k[e]"], ["out[i, b] -= k * x[i, b]"])
    if feat.duffings:
        _element_loop(c, "d_node", ["i = d_node[e]", "l = d_l[e]"],
                      ["xi = x[i, b]", "out[i, b] -= l * xi * xi * xi"])
    if feat.couplings:
        _element_loop(c, "c_i", ["i = c_i[e]", "j = c_j[e]", "k = c_k[e]", "ka = c_ka[e]",
                                 "a = k / ka"],
                      ["s = x[i, b] - a * x[j, b]", "out[i, b] -= ka * s", "out[j, b] += k * s"])
    if feat.quads:
        _element_loop(c, "q_i", ["i = q_i[e]", "j = q_j[e]", "g = q_g[e]", "a = q_a[e]",
                                 "g2a = q_g2a[e]"],
                      ["xi = x[i, b]", "s = xi * xi - a * x[j, b]",
                       "out[i, b] -= g2a * xi * s", "out[j, b] += g * s"])
    if feat.dashpots:
        _emit_dashpots(c)
    if feat.monomials:
        _emit_monomials(c)
    if feat.in_forces:
        _element_loop(c, "fi_node", ["i = fi_node[e]", "gn = fi_gain[e]", "ch = fi_chan[e]"],
                      ["out[i, b] += gn * uc[ch, b]"])
    if feat.common_forces:
        _element_loop(c, "fc_node", ["i = fc_node[e]", "fv = fc_gain[e] * grow[e]"],
                      ["out[i, b] += fv"])
    c("for i in range(n):")
    c.indent()
    c("mi = minv[i]")
    _loop_b(c, ["out[i, b] *= mi"])
    c.dedent()
    c.dedent()


_ROW = re.compile(r"\b(x|v|out)\[(i|j), b\]")


def _element_loop(c: _Code, index: str, head: list[str], inner: list[str]) -> None:
    """Loop over elements; rows of the state are taken as views first (measured faster: the
    inner batch loop then indexes a 1-D row, which LLVM vectorises more readily)."""
    c(f"for e in range({index}.shape[0]):")
    c.indent()
    for s in head:
        c(s)
    rows = sorted({m.group(0) for s in inner for m in _ROW.finditer(s)})
    for r in rows:
        m = _ROW.match(r)
        c(f"{m.group(1)}_{m.group(2)} = {m.group(1)}[{m.group(2)}]")
    _loop_b(c, [_ROW.sub(lambda m: f"{m.group(1)}_{m.group(2)}[b]", s) for s in inner])
    c.dedent()


def _emit_dashpots(c: _Code) -> None:
    c("for e in range(b_i.shape[0]):")
    c.indent()
    c("i = b_i[e]")
    c("j = b_j[e]")
    c("bb = b_b[e]")
    c("if j < 0:  # to ground")
    c.indent()
    _loop_b(c, ["out[i, b] -= bb * v[i, b]"])
    c.dedent()
    c("else:")
    c.indent()
    _loop_b(c, ["r = bb * (v[i, b] - v[j, b])", "out[i, b] -= r", "out[j, b] += r"])
    c.dedent(2)


def _emit_monomials(c: _Code) -> None:
    # Each factor position contributes its partial derivative; summing them over positions is
    # the product rule, so repeated variables need no special case.
    c("for e in range(p_c.shape[0]):")
    c.indent()
    c("lo = p_ptr[e]")
    c("hi = p_ptr[e + 1]")
    c("for kf in range(lo, hi):")
    c.indent()
    c("i = p_var[kf]")
    c("ex = p_exp[kf]")
    c("for b in range(nb_):")
    c.indent()
    c("term = p_c[e] * ex * x[i, b] ** (ex - 1)")
    c("for ko in range(lo, hi):")
    c.indent()
    c("if ko != kf:")
    c("    term *= x[p_var[ko], b] ** p_exp[ko]")
    c.dedent()
    c("out[i, b] -= term")
    c.dedent(3)


def _emit_run(c: _Code, feat: Features, opts: KernelOptions, tab: Tableau) -> None:
    s_count = tab.stages
    acc_args = ", ".join(accel_args(feat))
    # Serial and nogil: the runtime runs chunks on threads. numba's parallel=True (prange)
    # measured as fast but compiled 3-4x slower (22 s against 6 s of CPU for one oscillator).
    c("@nb.njit(cache=True, error_model=\"numpy\", nogil=True)")
    c(f"def run({', '.join(run_args(feat, opts))}):")
    c.indent()
    c('"""Integrate chunks c0..c1-1 of `chunk` runs (columns of x0) for nsteps steps of h."""')
    c("n, runs = x0.shape")
    c("nch = u.shape[1]")
    _emit_coefficients(c, tab)
    c("for ci in range(c0, c1):")
    c.indent()
    c("lo_ = ci * chunk")
    c("nb_ = min(runs, lo_ + chunk) - lo_")
    c("x = np.empty((n, nb_), FT)")
    c("v = np.empty((n, nb_), FT)")
    c("xs = np.empty((n, nb_), FT)")
    for s in range(s_count):
        c(f"kv{s} = np.empty((n, nb_), FT)")
        if s > 0:
            c(f"vs{s} = np.empty((n, nb_), FT)")
    c("uc = np.zeros((max(nch, 1), nb_), FT)")
    c("for i in range(n):")
    c("    for b in range(nb_):")
    c("        x[i, b] = x0[i, lo_ + b]")
    c("        v[i, b] = v0[i, lo_ + b]")
    _emit_reduction_init(c, opts)
    if opts.record:
        c("for p in range(rec_node.shape[0]):")
        c("    for b in range(nb_):")
        c("        rec[p, lo_ + b, 0] = v[rec_node[p], b] if rec_isv[p] else x[rec_node[p], b]")
    c("for step in range(nsteps):")
    c.indent()
    c("sub = step % substeps")
    c("k0 = step // substeps")
    for s in range(s_count):
        _emit_stage(c, feat, opts, tab, s, acc_args)
    _emit_combine(c, tab)
    _emit_step_end(c, opts)
    c.dedent()
    c("for i in range(n):")
    c("    for b in range(nb_):")
    c("        xf[i, lo_ + b] = x[i, b]")
    c("        vf[i, lo_ + b] = v[i, b]")
    _emit_reduction_store(c, opts)
    c.dedent(2)


def _emit_coefficients(c: _Code, tab: Tableau) -> None:
    """h-scaled tableau coefficients as typed constants (keeps float32 kernels in float32)."""
    for s, row in enumerate(tab.a):
        for j, a in enumerate(row):
            if a != 0.0:
                c(f"ha{s}_{j} = FT(h * {a!r})")
    for s, b in enumerate(tab.b):
        if b != 0.0:
            c(f"hb{s} = FT(h * {b!r})")
            c(f"hbd{s} = h * {b!r}")


def _stage_velocity(s: int) -> str:
    return "v" if s == 0 else f"vs{s}"


def _emit_stage(c: _Code, feat: Features, opts: KernelOptions, tab: Tableau, s: int,
                acc_args: str) -> None:
    c(f"# stage {s}: c = {tab.c[s]!r}")
    row = [(j, a) for j, a in enumerate(tab.a[s]) if a != 0.0]
    if s == 0:
        xs_name = "x"
    else:
        xs_name = "xs"
        xterm = " + ".join(f"ha{s}_{j} * {_stage_velocity(j)}[i, b]" for j, _ in row) or "0.0"
        vterm = " + ".join(f"ha{s}_{j} * kv{j}[i, b]" for j, _ in row) or "0.0"
        c("for i in range(n):")
        c("    for b in range(nb_):")
        c(f"        xs[i, b] = x[i, b] + {xterm}")
        c(f"        vs{s}[i, b] = v[i, b] + {vterm}")
    if feat.in_forces:
        # Linear interpolation of the input samples (grid step h * substeps) at the stage time.
        c(f"pos = (sub + {tab.c[s]!r}) / substeps")
        c("kk = k0 + int(pos)")
        c("fr = FT(pos - int(pos))")
        c("for ch in range(nch):")
        c("    for b in range(nb_):")
        c("        uc[ch, b] = (FT(1.0) - fr) * u[lo_ + b, ch, kk] + fr * u[lo_ + b, ch, kk + 1]")
    grow = f"g[step, {s}]" if feat.common_forces else "g[0, 0]"
    c(f"accel({xs_name}, {_stage_velocity(s)}, kv{s}, uc, {grow}, {acc_args})")
    if tab.b[s] != 0.0:
        _emit_stage_reductions(c, feat, opts, s)


def _emit_stage_reductions(c: _Code, feat: Features, opts: KernelOptions, s: int) -> None:
    """Quadrature of power over the step with the tableau weights (consistent with RK)."""
    vs = _stage_velocity(s)
    if opts.work and feat.in_forces:
        c("for e in range(fi_node.shape[0]):")
        c("    for b in range(nb_):")
        c(f"        w_in[e, b] += hbd{s} * fi_gain[e] * uc[fi_chan[e], b] * {vs}[fi_node[e], b]")
    if opts.work and feat.common_forces:
        c("for e in range(fc_node.shape[0]):")
        c(f"    fv = fc_gain[e] * g[step, {s}, e]")
        c("    for b in range(nb_):")
        c(f"        w_c[e, b] += hbd{s} * fv * {vs}[fc_node[e], b]")
    if opts.dissipation:
        c("for d in range(ds_i.shape[0]):")
        c("    i = ds_i[d]")
        c("    j = ds_j[d]")
        c("    for b in range(nb_):")
        c(f"        dv = {vs}[i, b] - ({vs}[j, b] if j >= 0 else 0.0)")
        c(f"        dsacc[d, b] += hbd{s} * ds_b[d] * dv * dv")


def _emit_combine(c: _Code, tab: Tableau) -> None:
    xterm = " + ".join(f"hb{s} * {_stage_velocity(s)}[i, b]"
                       for s, b in enumerate(tab.b) if b != 0.0)
    vterm = " + ".join(f"hb{s} * kv{s}[i, b]" for s, b in enumerate(tab.b) if b != 0.0)
    c("for i in range(n):")
    c("    for b in range(nb_):")
    c(f"        x[i, b] += {xterm}")
    c(f"        v[i, b] += {vterm}")


def _emit_step_end(c: _Code, opts: KernelOptions) -> None:
    c("k1 = step + 1")
    if opts.msq:
        c("for m in range(ms_node.shape[0]):")
        c("    if ms_lo[m] <= k1 and k1 <= ms_hi[m]:")
        c("        for b in range(nb_):")
        c("            q = v[ms_node[m], b] if ms_isv[m] else x[ms_node[m], b]")
        c("            msacc[m, b] += q * q")
    if opts.gram:
        _emit_gram_step(c)
    if opts.record:
        c("if k1 % rec_every == 0:")
        c("    r = k1 // rec_every")
        c("    for p in range(rec_node.shape[0]):")
        c("        for b in range(nb_):")
        c("            rec[p, lo_ + b, r] = v[rec_node[p], b] if rec_isv[p] else x[rec_node[p], b]")
    # Divergence guard: NaN/Inf or a state beyond `limit` stops the chunk; the caller raises.
    c("if k1 % check_every == 0 or k1 == nsteps:")
    c.indent()
    c("bad = False")
    c("for b in range(nb_):")
    c.indent()
    c("worst = 0.0")
    c("wi = -1")
    c("for i in range(n):")
    c("    ax = abs(x[i, b])")
    c("    if not (ax <= limit and abs(v[i, b]) <= limit):")
    c("        ax = np.inf")
    c("    if wi < 0 or ax > worst:")
    c("        worst = ax")
    c("        wi = i")
    c("if not worst <= limit:")
    c("    status[lo_ + b] = k1")
    c("    bad_node[lo_ + b] = wi")
    c("    bad = True")
    c.dedent()
    c("if bad:")
    c("    break")
    c.dedent()


def _emit_gram_step(c: _Code) -> None:
    # Leaky sum: decay every group by exp(-h/tau), then add this step's weighted products;
    # stays bounded (no exp(t/tau) growth) and needs no stored trajectory.
    c("for gq in range(gracc.shape[0]):")
    c("    dg = gr_decay[gq]")
    c("    for b in range(nb_):")
    c("        gracc[gq, b] *= dg")
    c("for p in range(gr_i.shape[0]):")
    c("    xi_ = x[gr_i[p]]")
    c("    xj_ = x[gr_j[p]]")
    c("    gp = gr_g[p]")
    c("    wp = gr_w[p]")
    c("    for b in range(nb_):")
    c("        gracc[gp, b] += wp * xi_[b] * xj_[b]")


def _emit_reduction_init(c: _Code, opts: KernelOptions) -> None:
    if opts.work:
        c("w_in = np.zeros((work_in.shape[0], nb_))")
        c("w_c = np.zeros((work_c.shape[0], nb_))")
    if opts.dissipation:
        c("dsacc = np.zeros((ds_i.shape[0], nb_))")
    if opts.msq:
        c("msacc = np.zeros((ms_node.shape[0], nb_))")
    if opts.gram:
        c("gracc = np.zeros((gram.shape[0], nb_))")
        c("for p in range(gr_i.shape[0]):")
        c("    for b in range(nb_):")
        c("        gracc[gr_g[p], b] += gr_w[p] * x[gr_i[p], b] * x[gr_j[p], b]")


def _emit_reduction_store(c: _Code, opts: KernelOptions) -> None:
    pairs = []
    if opts.work:
        pairs += [("w_in", "work_in"), ("w_c", "work_c")]
    if opts.dissipation:
        pairs.append(("dsacc", "diss"))
    if opts.msq:
        pairs.append(("msacc", "msq"))
    if opts.gram:
        pairs.append(("gracc", "gram"))
    for local, out in pairs:
        c(f"for r in range({local}.shape[0]):")
        c("    for b in range(nb_):")
        c(f"        {out}[r, lo_ + b] = {local}[r, b]")
