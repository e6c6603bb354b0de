"""springc.sim.plan: without a named integrator, `springc sim` and `Netlist.simulate` choose
one for 1e-3, and on the benchmark's feature extractor (8 Mel filter pairs, squarers,
low-pass) the choice is within 1e-3 of a fine reference where RK4 at one step per sample,
the old default, is not."""

from __future__ import annotations

import numpy as np
import pytest

from springc.bench.suite import feature_extractor, speech_like
from springc.check import check
from springc.errors import UsageError
from springc.lang import load_text
from springc.sim import plan
from springc.sim.simulate import simulate

RATE = 32000.0
SECONDS = 0.06


def worst_error(got: dict, ref: dict) -> float:
    """Worst probe's relative L2 error of run 0."""
    return max(float(np.linalg.norm(got[k][0] - ref[k][0]) / np.linalg.norm(ref[k][0]))
               for k in ref)


@pytest.fixture(scope="module")
def feature():
    net = check(feature_extractor(), judge_step=False)
    u = speech_like(SECONDS, RATE, 1)
    ref = simulate(net, u, tstep=1 / RATE, tstop=SECONDS, method="exp-rk4", substeps=16).probes
    return net, u, ref


def test_default_choice_on_the_feature_extractor_is_within_1e_3(feature) -> None:
    net, u, ref = feature
    steps = plan.integration(net, None, None, None, 1 / RATE, SECONDS, u)
    assert steps.choice and steps.choice.startswith(f"chose {steps.method}")
    got = simulate(net, u, tstep=1 / RATE, tstop=SECONDS, method=steps.method,
                   substeps=steps.substeps).probes
    assert worst_error(got, ref) <= plan.DEFAULT_TOLERANCE


def test_the_old_default_was_not(feature) -> None:
    net, u, ref = feature
    old = simulate(net, u, tstep=1 / RATE, tstop=SECONDS, method="rk4", substeps=1).probes
    assert worst_error(old, ref) > 10 * plan.DEFAULT_TOLERANCE


NET = """.title plan
M1 a m=1 b=0.5
K1 a k=100
.probe x(a)
.tran 1m 1
"""


def test_a_named_integrator_is_kept() -> None:
    net = check(load_text(NET))
    assert plan.integration(net, None, "rk38", None, None, None) == plan.Steps("rk38", None)
    assert plan.integration(net, None, None, 3, None, None) == plan.Steps(None, 3)
    options = check(load_text(NET + ".options method=ssprk3\n"))
    assert plan.integration(options, None, None, None, None, None).choice is None


def test_a_tolerance_with_a_method_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="chooses the method"):
        plan.integration(check(load_text(NET)), 1e-3, "rk4", None, None, None)


def test_an_unreachable_default_names_the_options() -> None:
    stiff = NET.replace("k=100", "k=1e12").replace(".tran 1m 1", ".tran 1 1000")
    with pytest.raises(UsageError, match="default accuracy target") as err:
        plan.integration(check(load_text(stiff), judge_step=False), None, None, None, None,
                         None)
    assert "--tolerance" in err.value.format()
