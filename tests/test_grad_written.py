"""springc.grad.written: the adjoint written out per network gives the values and gradients
of `springc.grad.adjoint`'s loops over element arrays, on a network with every term kind
and reduction it writes, checkpointed or not."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from springc.check import check
from springc.grad import coefficient_gradient, lanes, written
from springc.lang import load_text

# three masses, every element kind the written kernels write, two input channels and a
# shared source
NET = """
M1 x m=1 b=0.05 x0=0.3
M2 y m=2 b=0.1 v0=0.2
M3 z m=1.5
K1 x k=20
K2 y k=5
K3 z k=9
D1 x l=4
D2 z l=2
C1 x y k=3 a=1.5
Q1 x y g=0.7 a=1.5
Q2 y z g=0.4 a=0.8
B1 x z b=0.3
B2 z 0 b=0.05
F1 x in(0) gain=2
F2 z in(1) gain=1.5
F3 y sin(1 1.2 0.5) gain=0.8
.tran 10ms 0.5
"""

SPECS = ["msq:x(z)", "msq:v(x):0.1:0.3", "work:in", "dissipated:all", "final:x(y)",
         "gram:0.2:x,z"]
WEIGHTS = {"dissipated:all": -2.0, "gram:0.2:x,z": [1.0, -0.5, 0.25]}


def _gradient(monkeypatch, use_written: bool, every: int | None = None, runs: int = 2,
              options: str = ""):
    """One thread; the element loops a run at a time (their 1-lane copy, the cheapest to
    compile, which test_grad's lanes test compares with their 2-lane copy)."""
    if not use_written:
        monkeypatch.setattr(written, "eligible", lambda net: False)
        monkeypatch.setattr(lanes, "CHOICES", (1,))
    monkeypatch.setattr(importlib.import_module("springc.sim.execute"), "threads", lambda: 1)
    net = check(load_text(NET.replace(".tran", options + ".tran"), "<written>"))
    rng = np.random.default_rng(3)
    inputs = 0.5 * rng.standard_normal((runs, 2, 51))
    return coefficient_gradient(net, SPECS, inputs, input_rate=100.0, weights=WEIGHTS,
                                every=every)


RK38 = ".options substeps=2 method=rk38\n"


@pytest.mark.parametrize(("every", "runs", "width", "options"),
                         [(None, 2, 1, ""), (7, 2, 1, ""), (7, 5, 4, RK38)],
                         ids=["whole", "every7", "every7-5runs-rk38x2"])
def test_written_kernels_match_the_element_loops(monkeypatch, every, runs, width, options):
    """Whole or checkpointed; chunks of one run, and 5 runs in a 4-lane chunk and a padded
    one. The last case also takes another tableau and substeps: rk38 (stages reading two
    earlier ones, two stages at one time) at 2 substeps a sample, the inputs interpolated
    between samples as the element loops do (one written kernel for both: each is a compile
    of 6-8 s)."""
    ours = _gradient(monkeypatch, True, every, runs, options)
    assert ours.info["lanes"] == width and written.eligible(check(load_text(NET)).net)
    assert ours.info["settings"].substeps == (2 if options else 1)
    assert ours.info["settings"].method == ("rk38" if options else "rk4")
    loops = _gradient(monkeypatch, False, every, runs, options)
    for spec in SPECS:
        np.testing.assert_allclose(ours.values[spec], loops.values[spec], rtol=1e-12)
    for key, want in loops.coefficients.items():
        if not want.size:  # monomials
            continue
        scale = max(np.abs(want).max(), 1e-300)
        assert np.abs(ours.coefficients[key] - want).max() <= 1e-11 * scale, key


def test_monomials_are_not_written_out():
    net = check(load_text(NET.replace(".tran", "P1 c=0.1 x^2 y^2\n.tran"), "<m>")).net
    assert not written.eligible(net)
