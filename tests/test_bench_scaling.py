"""The scaling benchmark's networks and arithmetic (`springc.bench.lattices`,
`springc.bench.scaling`): the lattices built as arrays are the netlists their `.for` text
elaborates to, the fits recover known exponents, and the page says what was skipped."""

from __future__ import annotations

import numpy as np
import pytest

from springc.bench import scaling
from springc.bench.lattices import K0, KC, lattice_net, lattice_text, side_for
from springc.lang import load_text
from springc.lang.physics import stiffness_matrix


@pytest.mark.parametrize("dims, side", [(1, 6), (2, 3), (3, 3)])
def test_lattice_built_as_arrays_is_the_elaborated_text(dims, side):
    built = lattice_net(dims, side)
    built.validate()
    assert built.text() == load_text(lattice_text(dims, side)).text()


def test_lattice_stiffness_is_the_grounded_laplacian():
    net = lattice_net(2, 4)
    k = stiffness_matrix(net)
    # an inner site has 4 neighbours, a corner 2: k0 + kc * degree on the diagonal
    degree = np.array([[2, 3, 3, 2], [3, 4, 4, 3], [3, 4, 4, 3], [2, 3, 3, 2]]).ravel()
    np.testing.assert_allclose(np.diag(k), K0 + KC * degree)
    assert np.count_nonzero(k - np.diag(np.diag(k))) == 2 * 2 * 4 * 3


def test_sides_give_about_the_masses():
    assert [side_for(10**6, d) ** d for d in (1, 2, 3)] == [10**6, 10**6, 10**6]
    assert side_for(10**4, 3) ** 3 == 22**3


def test_fit_recovers_a_power_law_from_the_fit_start():
    masses = [10**3, 10**4, 10**5, 10**6]
    seconds = [5.0] + [2e-6 * m**1.1 for m in masses[1:]]  # the first: a fixed cost
    assert scaling.fit_exponent(masses, seconds) == pytest.approx(1.1)
    assert scaling.fit_exponent(masses[:2], seconds[:2]) is None


def result_with_a_skip() -> dict:
    row = {"elaborate": 0.1, "check": 0.2, "compile": 0.3, "simulate": 0.4, "threads": 1,
           "peak_gb": 0.2}
    return {
        "machine": {"cpus": 2, "load": 0.5, "when": "then"}, "steps": 1000,
        "cold_compile": {"one thread": 9.0, "split": 18.0},
        "cases": {"chain": [{"target": 10**4, "masses": 10**4, **row},
                            {"target": 10**5, "masses": 10**5, **row, "simulate": 4.0},
                            {"target": 10**6, "skipped": "did not finish within 900 s"}]},
        "ngspice": [{"target": 10**3, "masses": 1000, "export": 0.02, "ngspice": 11.0},
                    {"target": 10**4, "skipped": "predicted 132 s (> 60 s) from growth n^1.08"}],
        "threads": [{"masses": 10**5, "steps": 1000, "split": False, "threads": 1, "wall": 8.0,
                     "cpu": 8.0, "busiest": 8.0, "peak_gb": 0.3}],
        "fits": {"chain": {"elaborate": 0.0, "check": 0.0, "compile": 0.0, "simulate": 1.0}},
    }


def test_page_names_the_skipped_sizes_and_the_fits(tmp_path):
    paths = scaling.write_report(result_with_a_skip(), tmp_path)
    page = paths["md"].read_text()
    assert page.index("![time against masses") < page.index("| case | masses |")
    assert "| chain | ~1000000 | did not finish within 900 s |" in page
    assert "| ~10000 | skipped: predicted 132 s (> 60 s) from growth n^1.08 | |" in page
    assert "| chain | 0.00 | 0.00 | 0.00 | 1.00 |" in page
    assert "cold compiles: one thread 9.0 s, split 18.0 s" in page
    assert paths["png"].stat().st_size > 0 and paths["json"].exists()
