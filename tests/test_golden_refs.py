"""The stored DOP853 references (`tests/filter_refs.py`) are those of the networks the tests
simulate: same parameters, same input, and their first milliseconds computed again agree.
Regenerate with `python tests/regen_golden.py references`."""

from __future__ import annotations

import numpy as np
import pytest

import filter_refs

RECOMPUTED_S = 0.002  # 64 input samples: a few percent of a reference's cost


@pytest.mark.parametrize("name", list(filter_refs.REFERENCES))
def test_a_stored_reference_is_that_of_the_network_tested(name):
    with np.load(filter_refs.path(name)) as z:
        stored_params, stored_input = z["params"], z["input"]
    np.testing.assert_array_equal(stored_params, filter_refs.params(name))
    fa, lowpass, _, _ = filter_refs.REFERENCES[name]
    net, u = filter_refs.filter_net(fa, lowpass)
    np.testing.assert_array_equal(stored_input, u[0, 0])
    stored = filter_refs.load(name)
    assert sorted(stored) == sorted(p.label for p in net.probes)
    again = filter_refs.compute(name, RECOMPUTED_S)
    for label, y in again.items():
        want = stored[label][0, :len(y)]
        assert len(stored[label][0]) == round(filter_refs.SECONDS * filter_refs.RATE) + 1
        # both at the reference's own tolerance: they agree far below any test's threshold
        assert np.linalg.norm(y - want) <= 1e-8 * np.linalg.norm(want), label
