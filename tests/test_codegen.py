"""Code generation (text only) and the loader (numba compiles; on-disk cache)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from springc.kernels import codegen, loader
from springc.kernels.codegen import KernelOptions, generate
from springc.lang.ir import IRBuilder, Source, Tran
from springc.check import check

ROOT = str(Path(__file__).parents[1])


def small_net(k: float = 100.0, quad: bool = False, title: str = "small"):
    b = IRBuilder(title, "small.spr")
    b.mass("M1", "a", 1.0, 0.5)
    b.mass("M2", "c", 2.0)
    b.spring("K1", "a", k)
    b.coupling("C1", "a", "c", 10.0, a=2.0)
    if quad:
        b.quad("Q1", "a", "c", 3.0)
    b.force("F1", "a", Source("in"), 1.0)
    b.probe("x", "a")
    b.tran = Tran(1e-3, 0.1, None)
    return b.finish()


def test_only_present_element_kinds_are_generated():
    text = generate(small_net(), KernelOptions())
    assert "c_i" in text and "km" in text and "fi_node" in text
    for absent in ("q_i", "d_lm", "b_i", "p_c", "fc_node"):
        assert absent not in text
    assert "q_gi" in generate(small_net(quad=True), KernelOptions())


def test_header_names_netlist_options_and_hash():
    text = generate(small_net(), KernelOptions(method="rk38", precision="float32"))
    head = text.splitlines()[:8]
    assert head[1] == "# netlist: small.spr" and head[2] == "# title: small"
    assert "'method': 'rk38'" in head[3] and "'precision': 'float32'" in head[3]
    assert any(line.startswith("# body-hash: ") for line in head)
    assert "FT = np.float32" in text


def test_parameter_values_do_not_change_the_text():
    opts = KernelOptions()
    assert generate(small_net(k=1.0), opts) == generate(small_net(k=5e3), opts)
    assert generate(small_net(), opts) != generate(small_net(), KernelOptions(method="rk38"))


def test_body_is_kept_per_kinds_and_options_and_named_per_netlist():
    """A second netlist with the same element kinds reuses the body written for the first
    (a cache hit) and gets the same text as a fresh generation, under its own header."""
    opts = KernelOptions(lanes=4)
    codegen.hashed_body.cache_clear()
    first = generate(small_net(title="one"), opts)
    second = generate(small_net(k=7.0, title="two"), opts)
    assert codegen.hashed_body.cache_info().hits == 1
    codegen.hashed_body.cache_clear()
    assert generate(small_net(k=7.0, title="two"), opts) == second
    assert first.replace("# title: one", "# title: two") == second


def test_stages_follow_the_tableau():
    text = generate(small_net(), KernelOptions(method="ssprk3"))
    assert "elif s_ == 2:  # c = 0.5" in text and "s_ == 3" not in text
    assert "ha2_0 = FT(h * 0.25)" in text and "hb2 = FT(h * 0.6666666666666666)" in text


def test_codegen_does_not_import_numba():
    code = ("import sys; from springc.kernels.codegen import generate, KernelOptions; "
            "from tests.test_codegen import small_net; generate(small_net(), KernelOptions()); "
            "print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == "False"


def test_loader_writes_real_file_and_numba_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path))
    loader.forget()  # a kernel loaded by an earlier test would not be written here
    from springc.sim.simulate import simulate

    net = small_net()
    u = np.ones((1, 1, 101))
    # the shared kernel (not one run's register kernel)
    res = simulate(check(net), u, write_out=False)
    one_run = KernelOptions(lanes=codegen.choose_lanes(1))  # what simulate picks for 1 run
    text = generate(net, one_run)
    path = loader.kernel_path(text)
    assert path.parent == tmp_path and path.read_text() == codegen.shared_text(text)
    assert "# netlist: small.spr" in text and "small.spr" not in path.read_text()
    # another netlist with the same element kinds shares the compiled kernel
    assert loader.kernel_path(generate(small_net(title="other"), one_run)) == path
    assert path.name == f"springc_kernel_{codegen.kernel_hash(text)}.py"
    assert list((tmp_path / "__pycache__").glob(f"{path.stem}.run-*.nbi"))
    # step response from rest (F = 1, m = 1): x(a) = t^2/2 - b t^3/6 - k t^4/24 + O(t^5), with
    # b = 0.5 and k = 100 + 10/2 (spring and coupling)
    t = 2e-3
    assert abs(res.probes["x(a)"][0, 2] - (t**2 / 2 - 0.5 * t**3 / 6 - 105 * t**4 / 24)) < 2e-12
    # a second process loads the compiled code from the cache and gets the same numbers
    code = ("import numpy as np; from tests.test_codegen import small_net; "
            "from springc.check import check; from springc.sim.simulate import simulate; "
            "r = simulate(check(small_net()), np.ones((1, 1, 101))); "
            "print(repr(float(r.probes['x(a)'][0, -1])))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, "SPRINGC_CACHE": str(tmp_path)},
                         cwd=ROOT)
    assert float(out.stdout) == res.probes["x(a)"][0, -1]
