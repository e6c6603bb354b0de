"""springc.design.mvm: the matrix-vector multiplier by zero-mode engineering (paper Sec. III.A,
Louvet et al. 2024): zero modes exactly [I; Q], outputs Q times inputs in the operating band."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import subspace_angles

from springc.design import figures
from springc.lang import physics
from springc.design.mvm import design_mvm, load_matrix, mvm_text, write_mvm
from springc.errors import DataError, UsageError
from springc.lang import load_text

N = 24
M_SITE, KC = 1e-3, 10.0  # the delay line of the paper's Fig. 3d


@pytest.fixture(scope="module")
def q():
    """A random orthogonal 24 x 24 matrix."""
    q, _ = np.linalg.qr(np.random.default_rng(7).standard_normal((N, N)))
    return q


@pytest.fixture(scope="module")
def design(q):
    return design_mvm(q, m=M_SITE, kc=KC)


@pytest.fixture(scope="module")
def check():
    """The compiled 24 x 24 multiplier driven at its inputs (figures.experiment_mvm)."""
    return figures.experiment_mvm(N, seed=0)


def test_elements_sum_to_the_target_stiffness(design, q):
    """K = d [[I, -Q^T], [-Q, I]] from C elements and diagonal terms, to rounding."""
    d = design.stiffness
    target = d * np.block([[np.eye(N), -q.T], [-q, np.eye(N)]])
    assert np.abs(design.assembled_stiffness() - target).max() < 1e-12 * d


def test_target_has_exactly_the_zero_modes_i_q(design, q):
    w, v = np.linalg.eigh(design.K)
    assert np.abs(w[:N]).max() < 1e-12 * design.stiffness
    assert w[N:] == pytest.approx(2 * design.stiffness)
    assert subspace_angles(v[:, :N], np.vstack([np.eye(N), q])).max() < 1e-8


def test_each_element_obeys_the_sign_rules(design):
    """C: k/a >= 0 with |a| = 1; the diagonal only ever needs negative bare x^2 terms, because
    the 1-norm of a unit column or row of Q is at least 1."""
    assert len(design.couplings) == N * N
    assert all(c.k / c.a > 0 and abs(c.a) == 1 for c in design.couplings)
    assert all(t.c < 0 for t in design.diagonal)


def test_masses_halved_so_zero_modes_match_the_delay_line(design, q):
    """Modal mass of the zero modes [I; Q]: m_mvm (I + Q^T Q) = 2 m_mvm = m_site."""
    z = np.vstack([np.eye(N), q])
    assert z.T @ (design.m * z) == pytest.approx(M_SITE * np.eye(N), abs=1e-15)
    assert design.b == pytest.approx(math.sqrt(M_SITE * KC) / 2)
    assert design.stiffness == pytest.approx(1000 * KC)
    assert design.stiff_mode_hz() == pytest.approx(math.sqrt(1000) * design.band_edge_hz())


def test_written_netlist_reproduces_the_design_bit_for_bit(design, tmp_path):
    path = write_mvm(design, tmp_path / "mvm.spr")
    ports = " ".join(design.nodes)
    net = load_text(f'.include "{path.name}"\nXm {ports} mvm\n', str(tmp_path / "top.spr"))
    order = [net.node_index(name) for name in design.nodes]
    k = physics.stiffness_matrix(net)[np.ix_(order, order)]
    assert np.abs(k - design.K).max() < 1e-12 * design.stiffness
    assert net.mass() == pytest.approx(np.full(2 * N, design.m))
    assert net.element_counts() == {"M": 2 * N, "C": N * N, "P": 2 * N}
    assert max(len(line) for line in path.read_text().splitlines()) <= 100


def test_compiled_zero_modes_span_i_q(check):
    """Principal angles between the linear analysis' zero modes and [I; Q] below 1e-8."""
    assert check.angles.max() < 1e-8
    assert np.abs(check.zero_eigenvalues).max() < 1e-9 * check.design.stiffness / check.design.m


def test_outputs_equal_q_times_inputs_in_the_operating_band(check):
    """Driven anywhere below the delay line's band edge, x_out = Q x_in within 1%: the stiff
    modes take a share of the response that grows with frequency; above them the block is no
    multiplier at all."""
    band = check.f_hz <= check.design.band_edge_hz()
    assert band.sum() > 10
    assert check.rel_error[band].max() < 0.01
    assert np.all(np.diff(check.rel_error[band]) > 0)
    assert check.rel_error[check.f_hz > 2 * check.design.stiff_mode_hz()].min() > 0.5


def test_passes_the_compiler_checks(design, tmp_path):
    """`springc build`: the whole-potential check accepts the negative x^2 terms (PSD with N
    zero modes reported as info)."""
    from springc.check.compiler import build

    path = write_mvm(design, tmp_path / "mvm.spr")
    top = tmp_path / "top.spr"
    top.write_text(f'.include "{path.name}"\nXm {" ".join(design.nodes)} mvm\n'
                   f".tran 1e-4 0.01\n")
    report = build(top)
    assert report.dofs == 2 * N
    assert report.zero_modes == N
    assert report.to_json()["elements"] == {"M": 2 * N, "C": N * N, "P": 2 * N}


def test_non_orthogonal_matrix_is_refused():
    with pytest.raises(UsageError, match="not orthogonal"):
        design_mvm(np.array([[1.0, 0.5], [0.0, 1.0]]))


@pytest.mark.parametrize("array,reason", [
    (np.ones((2, 3)), "square"), (np.ones((3, 3)), "not orthogonal"), (np.eye(2, dtype=complex),
                                                                       "square real"),
])
def test_bad_matrix_files_name_the_file(tmp_path, array, reason):
    path = tmp_path / "q.npy"
    np.save(path, array)
    with pytest.raises(DataError, match=reason) as err:
        load_matrix(path)
    assert str(path) in err.value.format()


def test_unreadable_matrix_file(tmp_path):
    path = tmp_path / "q.npy"
    path.write_text("not numpy")
    with pytest.raises(DataError, match="cannot read"):
        load_matrix(path)


def test_signed_permutation_needs_no_correction():
    """For a signed permutation every coupling is a plain spring: no diagonal terms at all."""
    q = np.array([[0.0, -1.0], [1.0, 0.0]])
    d = design_mvm(q, kc=1.0)
    assert len(d.couplings) == 2 and d.diagonal == ()
    statements = [ln for ln in mvm_text(d).splitlines() if ln and ln[0] not in "*+."]
    assert [ln.split()[0][0] for ln in statements] == ["M"] * 4 + ["C"] * 2
