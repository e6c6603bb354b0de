"""Matrix-vector multiplier by zero-mode engineering (paper Sec. III.A; Louvet et al. 2024).

`N` input masses and `N` output masses are coupled so that the stiffness matrix has exactly the
zero modes `[x_in; x_out] = [I; Q] q` for an orthogonal `Q`: pushed slowly, the block moves only
along those modes, so the outputs follow `Q` times the inputs; every other mode is stiff and
lies far above the operating band.

Why the decomposition looks the way it does. A `C` element (k/a >= 0) or a `K` element is a
non-negative potential; a sum of such terms vanishes only where every term vanishes, so each
zero mode must satisfy x_p = a x_q for every coupling. For a dense `Q` no non-trivial vector of
the form [u; Q u] does, so an N-dimensional zero space cannot come from non-negative pairwise
elements alone. Instead the target is the whole quadratic form

    V = d/2 |x_out - Q x_in|^2,   K = d [[Q^T Q, -Q^T], [-Q, I]] = d [[I, -Q^T], [-Q, I]],

whose null space is exactly [I; Q] (Q^T Q = I) and whose other eigenvalue is 2d: the stiffness
`d` places the stiff modes at sqrt(2 d / m_mvm). Its off-diagonal entries -d Q_ji between
input i and output j are realised by `C` elements k = d Q_ji with leverage a = sign(Q_ji): each
adds |k| to both diagonals. The leverage magnitude 1 is the best choice: a coupling with
leverage a adds |k|/|a| + |k||a| >= 2|k| to the diagonal in total, and the diagonal must end at
exactly d, so |a| = 1 leaves the least to take back. What the diagonal then has in excess
(d (|Q_:,i|_1 - 1) at input i, d (|Q_j,:|_1 - 1) at output j, never negative because the 1-norm
of a unit vector is at least 1) is removed by bare monomials `P c=-e/2 x^2`; a deficit (none
with |a| = 1, kept for generality) would be a `K` spring. The elements sum to K exactly up to
rounding, and the whole potential is positive semidefinite, which is what the compiler's
whole-potential check accepts (the zero modes are reported as info).

Impedance matching with the delay lines (paper): a zero mode [I; Q] q has modal mass
m_mvm (I + Q^T Q) = 2 m_mvm, so the block's masses and dampings are half of a delay-line site's
for the zero modes to continue the line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.design.emit import SprWriter, num, write_atomic
from springc.errors import DataError, UsageError

ORTHOGONALITY_TOL = 1e-8  # max |Q^T Q - I| accepted as orthogonal
# d / kc: stiff modes sqrt(1000) = 32x above the line's band edge, so that driven anywhere in
# the band the stiff modes take under 1% of the response (about 2.3% at 10x)
DEFAULT_STIFFNESS_RATIO = 1000.0


@dataclass(frozen=True)
class Coupling:
    """A `C` element: V = k/(2a) (x_i - a x_j)^2 between node names i and j."""

    name: str
    i: str
    j: str
    k: float
    a: float


@dataclass(frozen=True)
class DiagonalTerm:
    """A `K` spring (c > 0: V = c/2 x^2, written k=c) or a bare monomial `P` (c < 0:
    V = c/2 x^2, written c=c/2) on one node."""

    name: str
    node: str
    c: float


@dataclass(frozen=True)
class MvmDesign:
    """A designed multiplier: `Q` (N x N), per-mass `m` and `b` (already halved), the delay
    line's `kc` it is matched to, the stiffness `d`, the target stiffness matrix `K` (2N x 2N,
    inputs first), its elements and an orthonormal basis `zero_modes` (2N x N) of [I; Q]."""

    Q: np.ndarray
    m: float
    b: float
    kc: float
    stiffness: float
    K: np.ndarray
    couplings: tuple[Coupling, ...]
    diagonal: tuple[DiagonalTerm, ...]
    zero_modes: np.ndarray

    @property
    def n(self) -> int:
        """Size N of the matrix (N inputs, N outputs)."""
        return self.Q.shape[0]

    @property
    def nodes(self) -> list[str]:
        """Port names in matrix order: in0 .. in{N-1}, out0 .. out{N-1}."""
        return [f"in{i}" for i in range(self.n)] + [f"out{j}" for j in range(self.n)]

    def stiff_mode_hz(self) -> float:
        """Frequency (Hz) of the stiff modes of the isolated block: sqrt(2 d / m) / 2 pi."""
        return math.sqrt(2 * self.stiffness / self.m) / (2 * math.pi)

    def band_edge_hz(self) -> float:
        """Upper band edge (Hz) of the matched delay line, 2 sqrt(kc / m_site) / 2 pi, with
        m_site = 2 m."""
        return 2 * math.sqrt(self.kc / (2 * self.m)) / (2 * math.pi)

    def assembled_stiffness(self) -> np.ndarray:
        """The stiffness matrix the elements add up to (should equal `K`)."""
        index = {name: p for p, name in enumerate(self.nodes)}
        h = np.zeros_like(self.K)
        for c in self.couplings:
            i, j = index[c.i], index[c.j]
            h[i, i] += c.k / c.a
            h[j, j] += c.k * c.a
            h[i, j] -= c.k
            h[j, i] -= c.k
        for t in self.diagonal:
            h[index[t.node], index[t.node]] += t.c
        return h


def design_mvm(Q: np.ndarray, *, m: float = 1.0, b: float | None = None, kc: float = 1.0,
               stiffness: float | None = None) -> MvmDesign:
    """Design the multiplier for orthogonal `Q`, matched to a delay line with site mass `m`,
    termination damping `b` (default: its impedance sqrt(m kc)) and coupling `kc`; the block's
    masses and dampings are m/2 and b/2. `stiffness` is d of the module docstring (N/m;
    default 1000 kc, stiff modes 32x above the line's band edge)."""
    Q = _check_orthogonal(np.asarray(Q, dtype=np.float64))
    if not (m > 0 and kc > 0):
        raise UsageError(f"mass and coupling must be positive, got m={m}, kc={kc}")
    b = math.sqrt(m * kc) if b is None else b
    d = DEFAULT_STIFFNESS_RATIO * kc if stiffness is None else stiffness
    if not (b >= 0 and d > 0):
        raise UsageError(f"need damping >= 0 and stiffness > 0, got b={b}, stiffness={d}")
    n = Q.shape[0]
    K = d * np.block([[np.eye(n), -Q.T], [-Q, np.eye(n)]])
    couplings = _couplings(Q, d)
    diagonal = _diagonal_terms(K, couplings, n)
    zero = np.vstack([np.eye(n), Q]) / math.sqrt(2.0)  # orthonormal: Q^T Q = I
    return MvmDesign(Q, m / 2, b / 2, kc, d, K, couplings, diagonal, zero)


def load_matrix(path: str | Path) -> np.ndarray:
    """A square orthogonal matrix from a `.npy` file; DataError naming the file otherwise."""
    path = Path(path)
    try:
        q = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - numpy raises many types for a bad file
        raise DataError(str(path), f"cannot read a .npy array ({exc})") from None
    if not isinstance(q, np.ndarray):  # an .npz archive under a .npy name
        raise DataError(str(path), "holds an .npz archive, not one .npy array")
    if q.ndim != 2 or q.shape[0] != q.shape[1] or q.shape[0] == 0 or q.dtype.kind not in "fiu":
        raise DataError(str(path), f"expected a square real matrix, got shape {q.shape} "
                        f"of {q.dtype}")
    try:
        return _check_orthogonal(q.astype(np.float64))
    except UsageError as err:
        raise DataError(str(path), err.message, "an orthogonal Q comes from e.g. "
                        "numpy.linalg.qr or the eigenvectors of a symmetric matrix") from None


def write_mvm(design: MvmDesign, path: str | Path, source: str = "") -> Path:
    """Write `.subckt mvm in0 .. in{N-1} out0 .. out{N-1}` to `path` (atomically); `source`
    names where Q came from, for the header."""
    return write_atomic(path, mvm_text(design, source))


def mvm_text(design: MvmDesign, source: str = "") -> str:
    """The `.spr` text of the design: a header with its numbers, then the subcircuit."""
    w = SprWriter()
    _header(w, design, source)
    w.blank()
    w.subckt("mvm", design.nodes)
    w.comment("masses: half of a delay-line site's mass and matched damping")
    for node in design.nodes:
        w.statement(f"M{node}", node, f"m={num(design.m)}", f"b={num(design.b)}")
    w.comment("off-diagonal stiffness -d Q[j,i] between in{i} and out{j}: leverage sign(Q[j,i])")
    for c in design.couplings:
        w.statement(c.name, c.i, c.j, f"k={num(c.k)}", f"a={num(c.a)}")
    if design.diagonal:
        w.comment("diagonal correction to exactly d: bare x^2 terms (the whole potential is PSD)")
    for t in design.diagonal:
        if t.c > 0:
            w.statement(f"K{t.name}", t.node, f"k={num(t.c)}")
        else:
            w.statement(f"P{t.name}", f"c={num(t.c / 2)}", f"{t.node}^2")
    w.ends("mvm")
    return w.text()


def _header(w: SprWriter, design: MvmDesign, source: str) -> None:
    n, d = design.n, design.stiffness
    w.comment(f"mvm: matrix-vector multiplier for a {n} x {n} orthogonal Q by zero-mode "
              f"engineering (paper Sec. III.A, Louvet et al. 2024). Written by "
              f"`springc design mvm`{' from ' + source if source else ''}.")
    w.comment("")
    w.comment("Ports: in0 .. in{N-1} (inputs), out0 .. out{N-1} (outputs), the block's own "
              "masses. Couple each input to its delay line's last site with the line's kc.")
    w.comment("Potential: V = d/2 |x_out - Q x_in|^2, stiffness K = d [[I, -Q^T], [-Q, I]]: "
              "zero modes exactly [x_in; x_out] = [I; Q] q, all other modes at K eigenvalue 2d. "
              "Driven well below the stiff modes, x_out = Q x_in.")
    w.comment(f"N = {n}, d = {num(d)} N/m, mass {num(design.m)} kg and damping "
              f"{num(design.b)} N s/m per node (half of the delay line's, for impedance "
              f"matching: modal mass of a zero mode is 2 m).")
    w.comment(f"Stiff modes of the isolated block at {design.stiff_mode_hz():.4g} Hz; band edge "
              f"of the matched delay line (kc = {num(design.kc)}) at "
              f"{design.band_edge_hz():.4g} Hz.")
    w.comment(f"Elements: {len(design.couplings)} C, "
              f"{sum(t.c > 0 for t in design.diagonal)} K, "
              f"{sum(t.c < 0 for t in design.diagonal)} P.")


def _check_orthogonal(q: np.ndarray) -> np.ndarray:
    if q.ndim != 2 or q.shape[0] != q.shape[1] or not np.all(np.isfinite(q)):
        raise UsageError(f"Q must be a finite square matrix, got shape {q.shape}")
    err = float(np.max(np.abs(q.T @ q - np.eye(q.shape[0]))))
    if err > ORTHOGONALITY_TOL:
        raise UsageError(f"Q is not orthogonal: max |Q^T Q - I| = {err:.3g} "
                         f"(tolerance {ORTHOGONALITY_TOL:g})")
    return q


def _couplings(Q: np.ndarray, d: float) -> tuple[Coupling, ...]:
    out = []
    for j, i in zip(*np.nonzero(Q)):
        k = d * Q[j, i]
        out.append(Coupling(f"Ci{i}o{j}", f"in{i}", f"out{j}", float(k), float(np.sign(k))))
    return tuple(sorted(out, key=lambda c: (int(c.i[2:]), int(c.j[3:]))))


def _diagonal_terms(K: np.ndarray, couplings: tuple[Coupling, ...],
                    n: int) -> tuple[DiagonalTerm, ...]:
    """What the diagonal still needs after the couplings: K where positive, P where negative."""
    nodes = [f"in{i}" for i in range(n)] + [f"out{j}" for j in range(n)]
    have = dict.fromkeys(nodes, 0.0)
    for c in couplings:
        have[c.i] += c.k / c.a
        have[c.j] += c.k * c.a
    terms = []
    for p, node in enumerate(nodes):
        need = K[p, p] - have[node]
        if need != 0.0:
            terms.append(DiagonalTerm(f"d{node}", node, float(need)))
    return tuple(terms)
