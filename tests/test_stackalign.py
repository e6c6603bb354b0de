"""Kernels ask LLVM for a 64-byte-aligned stack frame (`springc.stackalign`)."""

from __future__ import annotations

import re
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from springc.ir import IRBuilder, Tran
from springc.simulate import simulate
from springc.stackalign import align_stack


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


@pytest.mark.parametrize("method, write_out, runs", [
    ("rk4", False, 4),  # the shared kernel
    ("rk4", True, 1),  # a register kernel for one run
    ("rk4", True, 4),  # a register kernel for lanes
    ("strang-rk4", None, 4),  # split: exact blocks and RK4
    ("exp-heun3", None, 4),  # Lawson
])
def test_every_kernel_aligns_its_frame_first(method, write_out, runs):
    b = IRBuilder("oscillator")
    b.mass("M1", "a", 1.0, 1.0)
    b.spring("K1", "a", 100.0)
    b.probe("x", "a")
    b.tran = Tran(1e-3, 0.01, None)
    net = b.finish()
    res = simulate(net, np.zeros((runs, 1, 11)), method=method, write_out=write_out)
    assert np.isfinite(res.probes["x(a)"]).all()
    lines = Path(res.info["kernel"]).read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("def run("))
    assert lines[head + 2].strip() == "align_stack()"
    assert any(line.startswith("from springc.stackalign import align_stack  # ")
               for line in lines)
