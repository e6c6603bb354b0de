"""springc.grad.written: the adjoint written out per network gives the values and gradients
of `springc.grad.adjoint`'s loops over element arrays, on the network generated from every
element kind (`reference_nets.every_kind_netlist`, whose written-out gradients test_grad
checks against finite differences) and every reduction it writes, checkpointed or not."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from reference_nets import every_kind_netlist

from springc.check import check
from springc.grad import coefficient_gradient, lanes, written
from springc.lang import load_text

# every element kind, generated from the kinds (`reference_nets.every_kind_netlist`): the
# hub h, satellites s0-s2, input forces on channel 0 and shared sources
SPECS = ["msq:x(s2)", "msq:v(h):0.1:0.3", "work:in", "dissipated:all", "final:x(s1)",
         "gram:0.2:h,s2"]
WEIGHTS = {"dissipated:all": -2.0, "gram:0.2:h,s2": [1.0, -0.5, 0.25]}
RK4 = ".options method=rk4"
RK38 = ".options substeps=2 method=rk38"


def _gradient(monkeypatch, use_written: bool, every: int | None = None, runs: int = 2,
              options: str = RK4):
    """One thread; the element loops a run at a time (their 1-lane copy, the cheapest to
    compile, which test_grad's lanes test compares with their 2-lane copy)."""
    if not use_written:
        monkeypatch.setattr(written, "eligible", lambda net: False)
        monkeypatch.setattr(lanes, "CHOICES", (1,))
    monkeypatch.setattr(importlib.import_module("springc.sim.execute"), "threads", lambda: 1)
    net = check(load_text(every_kind_netlist(options)[0], "<written>"))
    rng = np.random.default_rng(3)
    inputs = 0.5 * rng.standard_normal((runs, 1, 51))
    return coefficient_gradient(net, SPECS, inputs, input_rate=100.0, weights=WEIGHTS,
                                every=every)


@pytest.mark.parametrize(("every", "runs", "width", "options"),
                         [(None, 2, 1, RK4), (7, 2, 1, RK4), (7, 5, 4, RK38)],
                         ids=["whole", "every7", "every7-5runs-rk38x2"])
def test_written_kernels_match_the_element_loops(monkeypatch, every, runs, width, options):
    """Whole or checkpointed; chunks of one run, and 5 runs in a 4-lane chunk and a padded
    one. The last case also takes another tableau and substeps: rk38 (stages reading two
    earlier ones, two stages at one time) at 2 substeps a sample, the inputs interpolated
    between samples as the element loops do (one written kernel for both: each is a compile
    of 6-8 s)."""
    ours = _gradient(monkeypatch, True, every, runs, options)
    net = check(load_text(every_kind_netlist(options)[0], "<written>")).net
    assert ours.info["lanes"] == width and written.eligible(net)
    assert ours.info["settings"].substeps == (2 if options == RK38 else 1)
    assert ours.info["settings"].method == ("rk38" if options == RK38 else "rk4")
    loops = _gradient(monkeypatch, False, every, runs, options)
    for spec in SPECS:
        np.testing.assert_allclose(ours.values[spec], loops.values[spec], rtol=1e-12)
    for key, want in loops.coefficients.items():
        if not want.size:  # monomials
            continue
        scale = max(np.abs(want).max(), 1e-300)
        assert np.abs(ours.coefficients[key] - want).max() <= 1e-11 * scale, key


def test_monomials_are_not_written_out():
    text = every_kind_netlist()[0].replace(".tran", "P1 c=0.1 h^2 s0^2\n.tran")
    net = check(load_text(text, "<m>")).net
    assert not written.eligible(net)
