"""Register kernels for lanes ask LLVM for a 64-byte-aligned stack frame
(`springc.kernels.stackalign`)."""

from __future__ import annotations

import re
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from springc.lang.ir import IRBuilder, Tran
from springc.sim import simulate as sm
from springc.sim.simulate import simulate
from springc.kernels.stackalign import align_stack
from springc.check import check


def _sum(a):
    s = 0.0
    for x in a:
        s += x
    return s


def _aligned_sum(a):
    align_stack()
    s = 0.0
    for x in a:
        s += x
    return s


def _asm(fn) -> str:
    return next(iter(fn.inspect_asm().values()))


def test_align_stack_realigns_the_frame_and_leaves_the_result():
    plain, aligned = nb.njit(_sum), nb.njit(_aligned_sum)
    a = np.arange(10.0)
    assert aligned(a) == plain(a) == 45.0
    realign = re.compile(r"andq\s+\$-64, %rsp")
    assert realign.search(_asm(aligned))
    assert not realign.search(_asm(plain))
    assert "alignstack(64)" in next(iter(aligned.inspect_llvm().values()))


@pytest.mark.parametrize("method, write_out, runs, aligned", [
    ("rk4", True, 16, True),  # a register kernel for lanes: its lane loop spills vectors
    ("rk4", False, 16, False),  # the shared kernel
    ("rk4", True, 1, False),  # a register kernel for one run: scalars
    ("strang-rk4", None, 16, False),  # split: exact blocks and RK4
    ("exp-heun3", None, 16, False),  # Lawson
])
def test_register_kernels_for_lanes_align_their_frame_first(method, write_out, runs, aligned,
                                                            monkeypatch):
    monkeypatch.setattr(sm, "threads", lambda: 2)  # 16 runs: lanes as on two cores
    b = IRBuilder("two coupled masses")
    for node, k in (("a", 100.0), ("c", 150.0)):
        b.mass(f"M{node}", node, 1.0, 1.0, x0=0.1)
        b.spring(f"K{node}", node, k)
        b.probe("x", node)
    b.coupling("C1", "a", "c", 20.0)
    b.tran = Tran(1e-3, 0.01, None)
    res = simulate(check(b.finish()), np.zeros((runs, 1, 11)), method=method, write_out=write_out)
    assert np.isfinite(res.probes["x(c)"]).all() and res.probes["x(c)"].any()
    lines = Path(res.info["kernel"]).read_text().splitlines()
    assert ("LANES = 1 " in "\n".join(lines)) == (runs == 1)
    head = next(i for i, line in enumerate(lines) if line.startswith("def run("))
    assert (lines[head + 2].strip() == "align_stack()") == aligned
    assert any(line.startswith("from springc.kernels.stackalign import align_stack  # ")
               for line in lines) == aligned
