"""The adjoint's force code, rendered from the element kinds of `springc.kernels.terms`.

Each kind's `terms.Physical` gives its force on each end as a template over the ends'
state, its netlist coefficients and its subexpressions (`temps`). `forward` renders one
element's force terms; `backward` the transpose of their Jacobian: the adjoint of each
subexpression, last to first, then of the state and of each coefficient, every partial
derivative taken by `springc.grad.calculus`, so a kind added to `terms.ELEMENTS` comes with
its gradient. A subexpression or derivative that reads only coefficients is a per-element
scalar (`head`: outside the lanes, where its divisions cost once); the rest is per lane.

Both adjoints render with these: the written-out kernels (`springc.grad.written`) name
every element's scalars apart (`elem`, `lane` suffixes), the element loops
(`loop_source`, appended to `springc.grad.adjoint` by `springc.grad.lanes`) index arrays.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field

from springc.grad import calculus
from springc.grad.model import BLOCKS
from springc.kernels.terms import ELEMENTS, Physical

def state_fields(p: Physical) -> set[str]:
    """The fields of kind p that change per lane and stage: its ends' state, its input
    channel's value {u}, its shared source's value {g}."""
    return {"xi", "xj", "vi", "vj"} | ({"u"} if p.channel else set()) | (
        {"g"} if p.signal else set())


@dataclass
class Forward:
    """One element's force: per-element statements, per-lane statements, and the signed
    term ('+ ...', '- ...') it adds to each end's force."""

    head: list[str]
    lane: list[str]
    force: dict[str, str]


@dataclass
class Backward:
    """The transpose of one element's force Jacobian applied to its ends' force adjoints:
    per-element and per-lane statements, and the terms ('+ ...') added to the adjoint of
    each state field and to the gradient of each coefficient."""

    head: list[str] = field(default_factory=list)
    lane: list[str] = field(default_factory=list)
    state: dict[str, list[str]] = field(default_factory=dict)
    params: dict[str, list[str]] = field(default_factory=dict)


def ends(p: Physical, ground: bool) -> list[tuple[str, str]]:
    """(end, force template) of each end the element moves (its i end alone at the ground)."""
    if ground:
        return [("i", p.ground)]
    return list(p.force)


def _fields(p: Physical, ground: bool) -> tuple[list[str], list[tuple[str, str, bool]]]:
    """The coefficients and the subexpressions the forces read, in order, each subexpression
    with whether it reads the state (per lane)."""
    used = " ".join(t for _, t in ends(p, ground))
    temps = list(p.temps)
    for name, temp in reversed(temps):  # subexpressions read by used ones are used
        if "{" + name + "}" in used:
            used += " " + temp
    lane: set[str] = set()
    out = []
    for name, temp in temps:
        if "{" + name + "}" not in used:
            continue
        reads = calculus.free(calculus.parse(temp))
        per_lane = bool(reads & (state_fields(p) | lane))
        if per_lane:
            lane.add(name)
        out.append((name, temp, per_lane))
    params = [f for f, _, _ in p.params if "{" + f + "}" in used]
    return params, out


def names(p: Physical, ground: bool, state: dict[str, str], elem: str, lane: str
          ) -> dict[str, str]:
    """Every field's code: the state as `state` gives it, coefficients and per-element
    subexpressions with the suffix `elem`, per-lane subexpressions with `lane`."""
    _, temps = _fields(p, ground)
    out = dict(state) | {f: f + elem for f, _, _ in p.params}
    out |= {n: n + (lane if per_lane else elem) for n, _, per_lane in temps}
    return out


def _fill(template: str, code: dict[str, str]) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: code[m.group(1)], template)


def forward(p: Physical, ground: bool, state: dict[str, str], elem: str, lane: str
            ) -> Forward:
    """The element's force terms, its fields named as `names` names them."""
    code = names(p, ground, state, elem, lane)
    _, temps = _fields(p, ground)
    out = Forward([], [], {})
    for name, temp, per_lane in temps:
        (out.lane if per_lane else out.head).append(f"{code[name]} = {_fill(temp, code)}")
    for end, template in ends(p, ground):
        out.force[end] = _fill(template, code).strip()
    return out


def backward(p: Physical, ground: bool, state: dict[str, str], elem: str, lane: str,
             fb: dict[str, str] | None = None) -> Backward:
    """The adjoint of the element's force terms, `fb[end]` the adjoint of each end's force
    (`fb_{end}` if not given: its `head` alone reads none): each subexpression's adjoint
    `{name}b{lane}`, each per-element derivative `d{name}_{field}{elem}`."""
    fb = fb or {"i": "fb_i", "j": "fb_j"}
    params, temps = _fields(p, ground)
    code = names(p, ground, state, elem, lane) | {f"fb_{e}": fb[e] for e, _ in ends(p, ground)}
    per_lane = {n for n, _, lanes in temps if lanes} | state_fields(p)
    adj: dict[str, list[ast.expr]] = {}
    out = Backward()

    wanted = {"xi", "xj", "vi", "vj"} | set(params) | {n for n, _, _ in temps}

    def spread(expr: ast.expr, seed: str, of: str) -> None:
        for f in sorted(calculus.free(expr) & wanted):
            d = calculus.derivative(expr, f)
            if calculus.is_zero(d):
                continue
            if not (calculus.free(d) & per_lane) and not _simple(d):
                name = f"d{of}_{f}"  # reads coefficients only: once per element
                code[name] = name + elem
                out.head.append(f"{code[name]} = {calculus.text(d, code)}")
                d = ast.Name(name)
            adj.setdefault(f, []).append(calculus.mul(ast.Name(seed), d))

    for end, template in ends(p, ground):
        spread(calculus.parse(template), f"fb_{end}", f"F{end}")
    for name, temp, _ in reversed(temps):
        if name not in adj:
            continue
        code[name + "b"] = f"{name}b{lane}"
        out.lane.append(f"{name}b{lane} = {calculus.text(_total(adj.pop(name)), code)}")
        spread(calculus.parse(temp), name + "b", name)
    for f, terms in adj.items():
        text = "+ " + calculus.text(_total(terms), code)
        (out.params if f in params else out.state).setdefault(f, []).append(text)
    return out


def _simple(expr: ast.expr) -> bool:
    """A name, a number or a name's negative: nothing to compute once per element."""
    if isinstance(expr, ast.UnaryOp) and isinstance(expr.op, ast.USub):
        expr = expr.operand
    return isinstance(expr, (ast.Name, ast.Constant))


def _total(terms: list[ast.expr]) -> ast.expr:
    out = terms[0]
    for t in terms[1:]:
        out = calculus.add(out, t)
    return out


def loop_source() -> str:
    """`forces` and `forces_vjp` of the element-loop adjoint (`springc.grad.adjoint`): the
    node terms and monomials written there, each kind of `terms.ELEMENTS` rendered here."""
    lines = ["", "", "@njit(**INLINE)", "def forces(md, x, v, uc, gs, f):",
             '    """Forces (not over mass) on every node at positions x, velocities v (dofs,',
             "    lanes), inputs uc (channel, lane) and shared source values gs (per shared",
             '    force)."""',
             "    nl = LANES or x.shape[1]",
             "    _own_forces(md, x, v, f)"]
    for p in ELEMENTS:
        lines += _loop(p, _loop_forward)
    lines += ["    _monomial_forces(md, x, f)", "", "", "@njit(**INLINE)",
              "def forces_vjp(md, x, v, uc, gs, fb, xb, vb, gr):",
              '    """Given fb, the adjoint of `forces`\' output, add its transpose into xb, vb',
              '    (adjoints of x and v) and into the coefficient gradient gr (row, lane)."""',
              "    nl = LANES or x.shape[1]",
              "    _own_vjp(md, x, v, fb, vb, gr)"]
    for p in ELEMENTS:
        lines += _loop(p, _loop_backward)
    lines += ["    _monomials_vjp(md, x, fb, xb, gr)"]
    return "\n".join(lines) + "\n"


def _loop(p: Physical, body) -> list[str]:
    """The loop over kind p's elements, branching on the ground end where it has one."""
    out = [f"    for e in range(md.{p.node_i}.shape[0]):", f"        i = md.{p.node_i}[e]"]
    if p.node_j:
        out.append(f"        j = md.{p.node_j}[e]")
    if p.channel:
        out.append(f"        ch = md.{p.channel}[e]")
    if p.ground is None:
        return out + body(p, False, "        ")
    return (out + ["        if j >= 0:"] + body(p, False, "            ")
            + ["        else:"] + body(p, True, "            "))


_LOOP_STATE = {"xi": "x[i, b]", "xj": "x[j, b]", "vi": "v[i, b]", "vj": "v[j, b]",
               "u": "uc[ch, b]", "g": "gs[e]"}


def _loads(p: Physical, pad: str) -> list[str]:
    return [f"{pad}{f}_ = md.{array}[e]" for f, array, _ in p.params]


def _loop_forward(p: Physical, ground: bool, pad: str) -> list[str]:
    code = forward(p, ground, _LOOP_STATE, "_", "")
    out = _loads(p, pad) + [pad + s for s in code.head] + [f"{pad}for b in range(nl):"]
    out += [f"{pad}    {s}" for s in code.lane]
    node = {"i": "i", "j": "j"}
    out += [f"{pad}    f[{node[e]}, b] = f[{node[e]}, b] {t}" for e, t in code.force.items()]
    return out


def _loop_backward(p: Physical, ground: bool, pad: str) -> list[str]:
    fb = {"i": "fb[i, b]", "j": "fb[j, b]"}
    fwd = forward(p, ground, _LOOP_STATE, "_", "")
    code = backward(p, ground, _LOOP_STATE, "_", "", fb)
    out = _loads(p, pad) + [pad + s for s in fwd.head + code.head]
    out += [f"{pad}for b in range(nl):"] + [f"{pad}    {s}" for s in fwd.lane + code.lane]
    rows = {"xi": "xb[i, b]", "xj": "xb[j, b]", "vi": "vb[i, b]", "vj": "vb[j, b]"}
    for f, terms in code.state.items():
        if f in rows:
            out.append(f"{pad}    {rows[f]} += {' '.join(terms).removeprefix('+ ')}")
    for f, terms in code.params.items():
        block = BLOCKS.index(dict((q, b) for q, _, b in p.params)[f])
        out.append(f"{pad}    gr[md.off[{block}] + e, b] += "
                   f"{' '.join(terms).removeprefix('+ ')}")
    return out
