"""netlists/lib/delayline.spr: the mechanical delay line (paper Sec. III.A, Eq. dispersion_rel,
Fig. 3d) with m = 1e-3, k_c = 10, k_l = 1e-5."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

from springc.design import figures
from springc.lang import load_text


@pytest.fixture(scope="module")
def pulse():
    return figures.experiment_pulse()


def test_pulse_delay_per_site_is_sqrt_m_over_kc(pulse):
    """Simulated arrival times over 40 sites: delay per site within 3% of sqrt(m/kc) = 10 ms
    (measured: 0.25% long, the dispersion of the pulse's spectrum)."""
    assert pulse.td == pytest.approx(math.sqrt(1e-3 / 10))
    assert pulse.delay_per_site == pytest.approx(pulse.td, rel=0.03)
    assert np.diff(pulse.arrival) == pytest.approx(10 * pulse.td, rel=0.03)


def test_matched_ends_do_not_reflect(pulse):
    """The far end's damping sqrt(m kc) absorbs the pulse: at site 50, what comes back after
    the pulse carries under 1% of its energy."""
    v = pulse.v[-1]
    t_back = pulse.arrival[-1] + 2 * 10 * pulse.td  # a reflection would be back by now
    late = pulse.t > t_back - 5 * pulse.td
    assert (v[late] ** 2).sum() < 0.01 * (v**2).sum()


def test_dispersion_relation_from_the_modes():
    """Paper Eq. (dispersion_rel): the modes of a free 40-site line are w(q) at q = pi j / n."""
    d = figures.experiment_dispersion(n=40)
    assert len(d.omega_modes) == 40
    assert d.omega_modes == pytest.approx(d.omega_theory, rel=1e-9)
    assert d.omega_modes[0] == pytest.approx(math.sqrt(1e-5 / 1e-3))  # k_l/m at q = 0
    # long waves (above the tiny gap of k_l, q >> sqrt(kl/kc) = 1e-3): sqrt(kc/m) sites/s
    q = np.linspace(0.02, 0.3, 50)
    assert d.group_velocity(q) == pytest.approx(math.sqrt(10 / 1e-3), rel=0.02)


def test_springc_modes_json_gives_the_dispersion_relation(tmp_path):
    """The same through the command line: `springc modes --json` of a free 40-site line."""
    net = tmp_path / "dl.spr"
    net.write_text('.include "delayline.spr"\nXd a b delayline n=40 td=0.01 kc=10\n')
    res = CliRunner().invoke(main, ["modes", str(net), "--json"])
    assert res.exit_code == 0, res.output
    omega = np.sort([m["omega"] for m in json.loads(res.output)["modes"]])
    q = np.pi * np.arange(40) / 40
    assert omega == pytest.approx(np.sqrt(1e-5 / 1e-3 + 4 * 10 / 1e-3 * np.sin(q / 2) ** 2),
                                  rel=1e-9)


@pytest.mark.parametrize("n", [2, 3, 4, 7])
def test_chain_structure_for_any_length(n):
    net = load_text(f'.include "delayline.spr"\nXd a b delayline n={n} td=0.01 kc=10\n')
    counts = net.element_counts()
    assert counts == {"M": n, "K": n, "C": n - 1}
    pairs = {(net.nodes[i], net.nodes[j]) for i, j in zip(net.couplings.i, net.couplings.j)}
    chain = ["a"] + [f"Xd.s{i}" for i in range(2, n)] + ["b"]
    assert pairs == set(itertools.pairwise(chain))


def test_terminations_are_matched():
    net = load_text('.include "delayline.spr"\n'
                    "Xd a b delayline n=5 td=0.02 kc=4 term=1 term_in=1\n")
    m = 0.02**2 * 4
    assert net.dashpots.b == pytest.approx([math.sqrt(m * 4)] * 2)
    assert sorted(net.nodes[i] for i in net.dashpots.i) == ["a", "b"]
