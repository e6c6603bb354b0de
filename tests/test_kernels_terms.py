"""The one description of the force terms (`springc.kernels.terms`): both renderings, the
per-node sums and the shared kernel's element loops, and the adjoint's rendering of each
kind's netlist form, evaluated as Python, give the accelerations of `springc.lang.physics`
for a network with every term kind."""

from __future__ import annotations

import string

import numpy as np
from reference_nets import every_kind

from springc.grad import model, render
from springc.kernels import terms
from springc.lang import physics
from springc.sim import marshal
from springc.sim import sources


def state(net, seed: int = 1) -> tuple[np.ndarray, ...]:
    """Random positions, velocities (n,), input channels (2,) and shared-signal values."""
    rng = np.random.default_rng(seed)
    fc = sources.common_forces(net)
    return (rng.normal(0, 0.1, net.n), rng.normal(0, 1.0, net.n), rng.normal(0, 1.0, 2),
            rng.normal(0, 1.0, len(fc)))


def reference(net, x, v, u, g) -> np.ndarray:
    """M^-1 (internal + damping + input + shared-signal forces), from physics."""
    f = (physics.internal_force(net, x[:, None]) + physics.damping_force(net, v[:, None]))[:, 0]
    fo = net.forces
    for e in sources.input_forces(net):
        f[fo.node[e]] += fo.gain[e] * u[fo.source[e].channel]
    for k, e in enumerate(sources.common_forces(net)):
        f[fo.node[e]] += fo.gain[e] * g[k]
    return f / net.mass()


def test_node_sums_give_the_physics_accelerations():
    net = every_kind()
    co = marshal.coefficient_arrays(net, np.float64)
    x, v, u, g = state(net)
    nodes = terms.node_terms(co, net.n)
    got = np.zeros(net.n)
    for i, node in enumerate(nodes):
        scope = {"FT": float, **co}
        for line in terms.scalar_loads(i, node):
            exec(line, scope, scope)  # noqa: S102 (generated source, the thing under test)
        expr = terms.node_sum(i, node, lambda j: f"x[{j}]", lambda j: f"v[{j}]",
                              lambda ch: f"u[{ch}]", lambda e: f"g[{e}]")
        got[i] = eval(expr, scope, {"x": x, "v": v, "u": u, "g": g})  # noqa: S307
    np.testing.assert_allclose(got, reference(net, x, v, u, g), rtol=1e-12, atol=1e-12)


def test_element_loops_give_the_physics_accelerations():
    """The linear part from `own_sum`, `ROW` and `INPUT`, then every kind's loop, one lane."""
    net = every_kind()
    co = marshal.coefficient_arrays(net, np.float64)
    x, v, u, g = state(net)
    ka = np.zeros((net.n, 1))
    for i in range(net.n):
        acc = eval(terms.own_sum(True, True, "bm[i]", "km[i]", "v[i]", "x[i]"),  # noqa: S307
                   {}, {"bm": co["bm"], "km": co["km"], "v": v, "x": x, "i": i})
        for e in range(co["l_ptr"][i], co["l_ptr"][i + 1]):
            acc += co["l_val"][e] * x[co["l_col"][e]]
        for e in range(co["fi_ptr"][i], co["fi_ptr"][i + 1]):
            acc += co["fi_gm"][e] * u[co["fi_chan"][e]]
        ka[i, 0] = acc
    for kind in terms.KINDS:
        for e in range(len(co[kind.node_i])):
            grounded = kind.ground is not None and co[kind.node_j][e] < 0
            code = terms.element_loop(kind, ground=grounded)
            scope = {**co, "e": e, "grow": g, "xa": x[:, None], "va": v[:, None], "ka": ka}
            if kind.ground is not None:
                scope["j"] = co[kind.node_j][e]
            for line in code.head + [s.replace("{b}", "0")
                                     for s in code.loads + code.arith + code.stores]:
                exec(line, scope, scope)  # noqa: S102
    np.testing.assert_allclose(ka[:, 0], reference(net, x, v, u, g), rtol=1e-12, atol=1e-12)


def test_every_kind_reads_only_what_it_declares():
    """A template field is a state field, a declared coefficient, a subexpression or the
    shared signal: a typo in a template fails here, not in a compiled kernel."""
    for kind in terms.KINDS:
        known = set(terms.STATE) | {f for f, _ in kind.coefs} | {n for n, _ in kind.temps}
        known |= {"g"} if kind.signal else set()
        texts = [t for _, t in kind.force + kind.temps] + [kind.ground or ""]
        for text in texts:
            fields = {f for _, f, _, _ in string.Formatter().parse(text) if f}
            assert fields <= known, (kind.name, fields - known)
    for p in terms.ELEMENTS:  # the adjoint's descriptions
        known = render.state_fields(p) | {f for f, _, _ in p.params} | {n for n, _ in p.temps}
        for text in [t for _, t in p.force + p.temps] + [p.ground or ""]:
            fields = {f for _, f, _, _ in string.Formatter().parse(text) if f}
            assert fields <= known, (p.name, fields - known)


def test_adjoint_descriptions_give_the_physics_forces():
    """Every kernel kind carries its force in the netlist's coefficients (`Kind.physical`),
    and those descriptions with the linear ones (`terms.ELEMENTS`, the adjoint's), rendered
    by `springc.grad.render` and evaluated as Python on the gradient's model, give the
    accelerations of physics."""
    assert all(kind.physical in terms.ELEMENTS for kind in terms.KINDS)
    net = every_kind()
    md = model.build(net)
    x, v, u, g = state(net)
    f = -md.bn * v
    for p in terms.ELEMENTS:
        for e, i in enumerate(getattr(md, p.node_i).tolist()):
            o = int(getattr(md, p.node_j)[e]) if p.node_j else -1
            scope = {"xi": x[i], "vi": v[i], "xj": x[o], "vj": v[o]}
            scope |= {"g": g[e]} if p.signal else {}
            scope |= {"u": u[int(getattr(md, p.channel)[e])]} if p.channel else {}
            scope |= {field: float(getattr(md, array)[e]) for field, array, _ in p.params}
            names = {field: field for field in scope}
            code = render.forward(p, p.ground is not None and o < 0, names, "", "")
            for line in code.head + code.lane:
                exec(line, {}, scope)  # noqa: S102
            for end, term in code.force.items():
                f[i if end == "i" else o] += eval("0.0 " + term, {}, scope)  # noqa: S307
    want = reference(net, x, v, u, g)
    np.testing.assert_allclose(f * md.minv, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_adjoint_descriptions_follow_the_gradient_layout():
    """`terms.ELEMENTS`' coefficients, in order, are the gradient's element blocks
    (`grad.model.BLOCKS` after the node blocks; the monomials' own loop keeps theirs), and
    name `Model` arrays; no field or subexpression name ends in a digit, which a lane or
    stage number appended to it could turn into another's name."""
    blocks = [b for p in terms.ELEMENTS for _, _, b in p.params]
    assert blocks == [b for b in model.BLOCKS[4:] if b != "pc"]
    for p in terms.ELEMENTS:
        arrays = [p.node_i, p.node_j, p.channel] + [a for _, a, _ in p.params]
        assert all(a in model.Model._fields for a in arrays if a), p.name
    for kind in terms.KINDS:
        names = [f for f, _ in kind.coefs + kind.temps]
        names += [f for f, _, _ in kind.physical.params] + [n for n, _ in kind.physical.temps]
        assert not [n for n in names if n[-1].isdigit()], kind.name
