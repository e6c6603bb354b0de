"""Register kernels for lanes ask LLVM for a 64-byte-aligned stack frame
(`springc.kernels.stackalign`)."""

from __future__ import annotations

import re
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from springc.lang.ir import IRBuilder, Tran
from springc.sim import execute
from springc.sim import simulate as sm
from springc.sim.simulate import simulate
from springc.kernels.stackalign import align_stack
from springc.check import check
from springc.kernels.codegen import KernelOptions
from springc.kernels.lower import kernel_netlist


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


def _two_masses():
    b = IRBuilder("two coupled masses")
    for node, k in (("a", 100.0), ("c", 150.0)):
        b.mass(f"M{node}", node, 1.0, 1.0, x0=0.1)
        b.spring(f"K{node}", node, k)
        b.probe("x", node)
    b.coupling("C1", "a", "c", 20.0)
    b.tran = Tran(1e-3, 0.01, None)
    return check(b.finish())


@pytest.mark.parametrize("runs, aligned", [
    (16, True),  # a register kernel for lanes: its lane loop spills vectors
    (1, False),  # a register kernel for one run: scalars
])
def test_register_kernels_for_lanes_align_their_frame_first(runs, aligned, monkeypatch):
    monkeypatch.setattr(execute, "threads", lambda: 2)  # 16 runs: lanes as on two cores
    res = simulate(_two_masses(), np.zeros((runs, 1, 11)), method="rk4", write_out=True)
    assert np.isfinite(res.probes["x(c)"]).all() and res.probes["x(c)"].any()
    lines = Path(res.info["kernel"]).read_text().splitlines()
    assert ("LANES = 1 " in "\n".join(lines)) == (runs == 1)
    assert lines[2].startswith("# force code: written out per node, the state in registers")
    head = next(i for i, line in enumerate(lines) if line.startswith("def run("))
    assert (lines[head + 2].strip() == "align_stack()") == aligned
    assert any(line.startswith("from springc.kernels.stackalign import align_stack  # ")
               for line in lines) == aligned


@pytest.mark.parametrize("method", ["rk4", "strang-rk4", "exp-heun3"])
def test_other_kernels_for_lanes_keep_their_frame(method):
    """The shared kernel and the split schemes' (exact blocks and RK4; Lawson) for 4 lanes,
    as generated (their text: `aligned_frame` holds for every form's generator)."""
    net = kernel_netlist(_two_masses().net)
    text = sm.kernel_source(net, KernelOptions(method=method, lanes=4))
    assert "LANES = 4 " in text and "def run(" in text
    assert "align_stack" not in text
