"""The network as the adjoint kernels read it: raw coefficients per element (no mass folded
in, so each one's gradient is a plain sum), and the layout of the gradient vector.

Per-node quantities (total mass, local damping, initial state) are sums over `M` elements,
so an element's gradient is its node's. As for the simulator's kernels, a monomial `P c x^2`
is a spring of stiffness 2c (`springc.kernels.lower`: the general monomial loops, with their
powers and the Hessian products of the reverse sweep, cost more than the rest of the keyword
spotter's classifier together), its gradient twice its spring's. `to_elements` maps a kernel
gradient back to the coefficient arrays of `springc.grad.params.COEFFICIENTS`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from springc.kernels.lower import kernel_netlist, squares
from springc.lang.ir import FlatNetlist
from springc.sim import sources


class Model(NamedTuple):
    """Index and coefficient arrays of every term kind (numba reads it as one argument)."""

    minv: np.ndarray
    bn: np.ndarray
    k_node: np.ndarray
    k_k: np.ndarray
    d_node: np.ndarray
    d_l: np.ndarray
    c_i: np.ndarray
    c_j: np.ndarray
    c_k: np.ndarray
    c_a: np.ndarray
    q_i: np.ndarray
    q_j: np.ndarray
    q_g: np.ndarray
    q_a: np.ndarray
    b_i: np.ndarray
    b_j: np.ndarray
    b_b: np.ndarray
    p_c: np.ndarray
    p_ptr: np.ndarray
    p_var: np.ndarray
    p_exp: np.ndarray
    fi_node: np.ndarray
    fi_gain: np.ndarray
    fi_chan: np.ndarray
    fc_node: np.ndarray
    fc_gain: np.ndarray
    off: np.ndarray  # start of each block of the gradient vector, BLOCKS order, then the end


# blocks of the gradient vector, in order: per node (m, b, x0, v0), then per element
BLOCKS = ("m", "b", "x0", "v0", "k", "l", "ck", "ca", "qg", "qa", "bb", "pc", "fi", "fc")
M, B, X0, V0, K, L, CK, CA, QG, QA, BB, PC, FI, FC = range(len(BLOCKS))


def build(net: FlatNetlist) -> Model:
    """The kernel model of `net` (input forces in `sources.input_forces` order, shared ones in
    `sources.common_forces` order, the orders of the simulator's input and source tables;
    the squares among the monomials as springs after `net`'s own, `kernel_netlist`)."""
    net = kernel_netlist(net)
    f = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
    i = lambda a: np.ascontiguousarray(a, np.int64)  # noqa: E731
    # node indices that are never negative: unsigned, so that numba indexes without its
    # negative-index wrap-around (as `marshal.coefficient_arrays` does)
    u = lambda a: np.ascontiguousarray(a, np.uint64)  # noqa: E731
    s, d, c, q, b, p, F = (net.springs, net.duffings, net.couplings, net.quads, net.dashpots,
                           net.monomials, net.forces)
    fi, fc = sources.input_forces(net), sources.common_forces(net)
    sizes = [net.n] * 4 + [len(s), len(d), len(c), len(c), len(q), len(q), len(b), len(p),
                           len(fi), len(fc)]
    return Model(
        minv=f(1.0 / net.mass()), bn=f(net.local_damping()),
        k_node=u(s.node), k_k=f(s.k), d_node=u(d.node), d_l=f(d.l),
        c_i=u(c.i), c_j=u(c.j), c_k=f(c.k), c_a=f(c.a),
        q_i=u(q.i), q_j=u(q.j), q_g=f(q.g), q_a=f(q.a),
        b_i=u(b.i), b_j=i(b.j), b_b=f(b.b),
        p_c=f(p.c), p_ptr=i(p.ptr), p_var=u(p.var), p_exp=i(p.exp),
        fi_node=u(F.node[fi]), fi_gain=f(F.gain[fi]),
        fi_chan=u([F.source[e].channel for e in fi]),
        fc_node=u(F.node[fc]), fc_gain=f(F.gain[fc]),
        off=i(np.concatenate([[0], np.cumsum(sizes)])),
    )


def to_elements(net: FlatNetlist, model: Model, grad: np.ndarray
                ) -> dict[tuple[str, str], np.ndarray]:
    """Kernel gradients (..., size) as gradients per element coefficient (..., elements),
    keyed as `springc.grad.params.COEFFICIENTS`."""
    blk = lambda k: grad[..., model.off[k]:model.off[k + 1]]  # noqa: E731
    node = net.masses.node
    moved, own = squares(net.monomials), len(net.springs)
    monomials = np.zeros(grad.shape[:-1] + (len(moved),))
    monomials[..., ~moved] = blk(PC)
    monomials[..., moved] = 2.0 * blk(K)[..., own:]  # k = 2c
    forces = np.zeros(grad.shape[:-1] + (len(net.forces),))
    forces[..., sources.input_forces(net)] = blk(FI)
    forces[..., sources.common_forces(net)] = blk(FC)
    return {
        ("masses", "m"): blk(M)[..., node], ("masses", "b"): blk(B)[..., node],
        ("masses", "x0"): blk(X0)[..., node], ("masses", "v0"): blk(V0)[..., node],
        ("springs", "k"): blk(K)[..., :own], ("duffings", "l"): blk(L),
        ("couplings", "k"): blk(CK), ("couplings", "a"): blk(CA),
        ("quads", "g"): blk(QG), ("quads", "a"): blk(QA),
        ("dashpots", "b"): blk(BB), ("monomials", "c"): monomials,
        ("forces", "gain"): forces,
    }
