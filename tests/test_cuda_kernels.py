"""The CUDA kernel form (`springc.kernels.cuda`, launched by `springc.sim.gpu`) against the CPU
kernels, under numba's CUDA simulator on a machine without a GPU, and `--device` without one.

numba reads NUMBA_ENABLE_CUDASIM when it is imported, so the comparison runs in a child
process (`scripts/cuda_compare.py tiny`, the script a GPU machine runs on the bench networks),
with NUMBA_DISABLE_JIT as well: the CPU kernels run as Python beside the simulated CUDA form
(their compiled forms are what the rest of the suite checks), and the two agree to the bit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from springc.errors import UsageError
from springc.kernels import cuda as cudagen
from springc.lang.ir import IRBuilder, Tran
from springc.sim import gpu
from springc_cli.main import main

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "cuda_compare.py"
NO_GPU = pytest.mark.skipif(gpu.cuda_present(simulator=False), reason="a GPU is present")


def test_cuda_form_gives_the_cpu_kernels_probes_and_reductions(tmp_path):
    """Every term kind, every reduction the CUDA form sums, RK4 and Heun3 (its stage of weight
    0), float64 and float32, the three force forms (written out, loops, a run split over a
    block's threads; split without monomials and shared signals, its combine folded into the
    last stage; in float32 one term of each list in registers, the rest looped), the steps
    streamed over many kernel calls; the Lawson schemes on the feature
    extractor, a run a thread and split; and a simulation that names no device inside
    `gpu.default_device('cuda')`. The float32 cases and exp-heun3 with no product fused
    (`fma` False: the CUDA form's products as `mul_rn`). Both run as Python: the same
    operations in the same order, so every probe and reduction is equal to the bit, in
    float32 too (on a GPU, against the compiled CPU kernels, to 1e-12 and 1e-5)."""
    out = tmp_path / "cases.json"
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "NUMBA_DISABLE_JIT": "1"}
    proc = subprocess.run([sys.executable, str(SCRIPT), "tiny", "--json", str(out)], env=env,
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert out.exists(), proc.stdout + proc.stderr
    cases = json.loads(out.read_text())
    assert len(cases) == 16
    for case in cases:
        want = ({"x(f0a)", "x(lp7)", "work:in", "dissipated:all", "energy"}
                if case["case"].startswith("feature extractor") else
                {"x(a)", "x(d)", "v(b)", "work:in", "dissipated:all", "energy",
                 "gram:0.005:a,c,d", "msq:v(d):0.002:0.006"})
        assert set(case["errors"]) >= want
        assert case["worst"] == 0.0, case
    limited = [c for c in cases if "at most 64 registers" in c["case"]]
    assert [(c["threads_per_run"], c["max_registers"], c["registers_held"])
            for c in limited] == [(32, 64, True)]
    warp = [c for c in cases if "feature extractor, split, a node a thread" in c["case"]]
    assert [(c["threads_per_run"], c["registers_held"]) for c in warp] == [(32, True)]
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_slot_tables_hold_each_nodes_first_terms_in_its_sum_order():
    """The split form's register tables against the CSR rows and node ends they are read
    from: entry q of node i is the node's q-th term of the list (zero past its count), an
    element kind's coefficients read through the end's element; the kernel reads them into
    scalars once and loops over the terms past them."""

    from springc.kernels import terms
    from springc.kernels.codegen import features
    from springc.kernels.lower import kernel_netlist
    from springc.sim.marshal import coefficient_arrays

    b = IRBuilder("triangle", "<test>")
    for node in "abc":
        b.mass(f"M{node}", node, 1.0, 0.0)
        b.spring(f"K{node}", node, 100.0)
    b.coupling("C1", "a", "b", 5.0, a=1.5)
    b.coupling("C2", "a", "c", 7.0, a=0.5)
    b.quad("Q1", "a", "c", 2e3, a=0.5)
    b.quad("Q2", "b", "c", 1e3, a=2.0)
    b.dashpot("B1", "b", "0", 3.0)
    b.probe("x", "a")
    b.tran = Tran(1e-3, 0.01, None)
    net = kernel_netlist(b.finish())
    co = coefficient_arrays(net, "float64")
    args = {**co, **terms.node_ends(co, net.n)}
    with gpu.layout(slot_max=1):
        threads, slots = gpu.split_layout(features(net), args, net.n)
    assert slots == (("row", 1, True), ("quad", 1, True), ("dashpot", 1, False))
    assert threads == 32  # one node a thread: a warp
    # written out per thread (one node at 256 threads): a row term, a quad's two end
    # variants, a dashpot's three (to ground too); over the limit, every term is looped
    code = cudagen.slot_code(cudagen.slot_lists(features(net)), [1, 1, 1], net.n, 256)
    assert code == 6
    with gpu.layout(slot_max=1, slot_code_max=code - 1):
        assert gpu.split_layout(features(net), args, net.n) == (cudagen.LOOP_THREADS, ())
    with pytest.raises(TypeError):  # a layout names only `cudagen.Layout`'s fields
        with gpu.layout(slot_maxx=1):
            pass
    opts = cudagen.CudaOptions("rk4", "float64", net.n, 0, probes=1, vneed=(True,) * net.n,
                               threads=2, slots=slots)
    mod_spec = cudagen._slot_spec(features(net), opts)
    tables = gpu._slot_tables(args, mod_spec, net.n)
    for i in range(net.n):
        row = range(int(co["l_ptr"][i]), int(co["l_ptr"][i + 1]))
        assert tables["sl_n"][0, i] == len(row)
        assert tables["sl_row_c"][0, i] == (co["l_col"][row[0]] if row else 0)
        assert tables["sl_row_w"][0, i] == (co["l_val"][row[0]] if row else 0.0)
        ends = range(int(args["quad_ptr"][i]), int(args["quad_ptr"][i + 1]))
        assert tables["sl_n"][1, i] == len(ends)
        if ends:
            e = args["quad_e"][ends[0]]
            assert tables["sl_quad_o"][0, i] == args["quad_o"][ends[0]]
            assert tables["sl_quad_end"][0, i] == args["quad_end"][ends[0]]
            assert (tables["sl_quad_a"][0, i], tables["sl_quad_gj"][0, i]) == (
                co["q_a"][e], co["q_gj"][e])
    assert tables["sl_dashpot_o"][0, 1] == -1  # b's dashpot: to ground
    assert max(tables["sl_n"][0]) == 2  # a's row: b and c, one held, one looped
    text = cudagen.generate(net, opts)
    assert "s_row0_0_w = sl_row_w[0, s_c0]" in text
    assert "for q_ in range(l_ptr[i] + np.uint64(1), l_ptr[i + 1]):" in text
    assert "dashpot_ptr[i] + np.uint64" not in text  # no node has two dashpot ends


def _one_mass():
    b = IRBuilder("one mass", "<test>")
    b.mass("M1", "a", 1.0, 1.0)
    b.spring("K1", "a", 100.0)
    b.probe("x", "a")
    b.tran = Tran(1e-3, 0.01, None)
    return b.finish()


def test_the_split_form_deals_nodes_of_the_same_terms_to_neighbouring_threads():
    """`gpu.deal`: every node once, ordered by the count of each list's terms (stiffness row
    first) and then by damping, ties in node order; on the 8x3 feature network (488 nodes,
    256 threads: slots of 32 neighbouring threads, warps) every warp then meets at most three
    kinds of node in a slot, where dealt in node order some meet six."""
    from springc.bench import networks as bn
    from springc.check import check
    from springc.kernels import terms
    from springc.kernels.codegen import features
    from springc.kernels.lower import kernel_netlist
    from springc.sim.marshal import coefficient_arrays

    args = {"l_ptr": np.array([0, 2, 3, 7, 8]), "q_ptr": np.array([0, 1, 1, 1, 1]),
            "bm": np.array([0.0, 1.0, 0.0, 0.0])}
    assert gpu.deal(args, ("l_ptr", "q_ptr"), 4).tolist() == [3, 1, 0, 2]
    net = kernel_netlist(check(bn.pipeline_features()).net)
    co = coefficient_arrays(net, "float64")
    args = {**co, **terms.node_ends(co, net.n)}
    ptrs = tuple(sl.ptr for sl in cudagen.slot_lists(features(net)))
    kind = np.stack([np.diff(args[p].astype(np.int64)) for p in ptrs] + [co["bm"] != 0], 1)

    def kinds_a_warp(order):
        return max(len({tuple(kind[i]) for i in order[p:min(p + 32, net.n)]})
                   for p in range(0, net.n, 32))

    order = gpu.deal(args, ptrs, net.n)
    assert sorted(order.tolist()) == list(range(net.n))
    assert kinds_a_warp(order) <= 3 < 6 <= kinds_a_warp(np.arange(net.n))


@pytest.mark.parametrize("name, threads, held, limit", [
    ("long delay line", 224, True, None),  # 201 nodes
    ("pipeline features 8x3", 512, True, 128),  # 488 nodes: 512 threads measured fastest
    ("564-dof kws network", 576, True, 112),
    ("pipeline classifier 8x3", 800, True, 80),  # 788 nodes
])
def test_split_runs_take_a_node_a_thread_within_a_multiprocessors_registers(
        name, threads, held, limit):
    """The split form's layout (`gpu.options`): one node a thread (the nodes rounded up to a
    warp) where the register form's code fits there, and registers a thread capped so that a
    block fits a multiprocessor's 65,536 (given out eight a thread, a warp at a time): an
    uncapped 134 a thread at 512 threads did not launch."""
    from springc.bench import networks as bn
    from springc.check import check
    from springc.kernels import terms
    from springc.kernels.codegen import features
    from springc.kernels.lower import kernel_netlist
    from springc.sim import reductions
    from springc.sim.marshal import coefficient_arrays

    net = {"long delay line": bn.long_delay_line, "pipeline features 8x3": bn.pipeline_features,
           "564-dof kws network": bn.kws_network,
           "pipeline classifier 8x3": bn.pipeline_classifier}[name]()
    net = kernel_netlist(check(net).net)
    co = coefficient_arrays(net, "float64")
    co = {**co, **terms.node_ends(co, net.n)}
    opts = gpu.options(net, None, "rk4", "float64", co, 0, reductions.plan([], net))
    assert (opts.threads, bool(opts.slots), opts.max_registers) == (threads, held, limit)
    assert cudagen.slot_code(cudagen.slot_lists(features(net)), [k for _, k, _ in opts.slots],
                             net.n, threads) <= cudagen.SLOT_CODE_MAX
    assert threads * (opts.max_registers or 255) <= cudagen.REGISTERS or threads <= 256
    assert [cudagen.register_limit(t) for t in (32, 256, 288, 1024)] == [None, None, 224, 64]


def test_a_run_of_more_nodes_than_a_block_has_threads_takes_256():
    """Past 1024 nodes (a block's most threads; in float32 only, a float64 run of so many
    exceeds a block's shared memory) the split form runs at `LOOP_THREADS`, its register
    lists where their code fits there."""
    from springc.kernels import terms
    from springc.kernels.codegen import features
    from springc.kernels.lower import kernel_netlist
    from springc.sim.marshal import coefficient_arrays

    chain = IRBuilder("chain", "<test>")
    for k in range(1100):
        chain.mass(f"M{k}", f"n{k}", 1.0, 0.0)
        chain.spring(f"K{k}", f"n{k}", 100.0)
        if k:
            chain.coupling(f"C{k}", f"n{k - 1}", f"n{k}", 5.0)
    chain.probe("x", "n0")
    chain.tran = Tran(1e-3, 0.01, None)
    long = kernel_netlist(chain.finish())
    co = coefficient_arrays(long, "float32")
    threads, held = gpu.split_layout(features(long), {**co, **terms.node_ends(co, long.n)},
                                     long.n)
    assert cudagen.node_threads(long.n) is None and threads == cudagen.LOOP_THREADS
    assert held == (("row", 2, False),)  # 5 nodes a thread of 2 row terms each: code fits


def test_generated_text_is_specialised_to_the_network():
    """The per-node form reads the coefficients into scalars once and indexes by constants;
    the loop form loops over the index arrays."""
    from springc.kernels.lower import kernel_netlist
    from springc.sim import reductions
    from springc.sim.marshal import coefficient_arrays

    net = kernel_netlist(_one_mass())
    co = coefficient_arrays(net, "float64")
    opts = gpu.options(net, None, "rk4", "float64", co, 1, reductions.plan([], net))
    text = cudagen.generate(net, opts)
    assert "bm0 = bm[0]" in text and "kv0[0] = - (bm0 * v[0] + km0 * x[0])" in text
    loops = cudagen.generate(net, cudagen.CudaOptions("rk4", "float64", 1, 0, probes=1,
                                                      vneed=(True,)))
    assert "for i in range(N):" in loops and "bm0 = bm[0]" not in loops
    split = cudagen.generate(net, cudagen.CudaOptions("rk4", "float64", 1, 0, probes=1,
                                                      vneed=(True,), threads=4))
    assert "x = cuda.shared.array(N, FT)" in split and "for i in deal[t:N:T]:" in split
    assert "kv2 = cuda.shared" in split and "kv3 = cuda.shared" not in split  # folded
    assert split.count("cuda.syncthreads()") == 8  # RK4: 3 stage states, 2 forces, the
    # combine, the start and the divergence check
    assert "MAX_REGISTERS = None " in split and "@cuda.jit(cache=True, **JIT)\n" in split
    capped = cudagen.generate(net, cudagen.CudaOptions("rk4", "float64", 1, 0, probes=1,
                                                       vneed=(True,), threads=4,
                                                       max_registers=64))
    assert "MAX_REGISTERS = 64 " in capped


def test_unfused_form_rounds_every_product_inside_the_kernel_alone():
    """`fma` False: every product inside the kernel function, and every `*=`, becomes a
    `mul_rn` call (NVVM then fuses none into a fused multiply-add); array sizes, which must
    stay compile-time constants, and module-level constants keep their products. The CPU
    kernel of the same netlist is compiled without LLVM's contraction."""
    from springc.kernels import codegen
    from springc.kernels.lower import kernel_netlist
    from springc.sim import reductions
    from springc.sim.marshal import coefficient_arrays

    text = cudagen.rounded_products(
        "M = 2 * 3\n"
        "def run(a, b, i):\n"
        "    s = cuda.local.array(2 * M, FT)\n"
        "    s[i * 2] = a * b + a * (b * a)\n"
        "    s[0] *= a - b\n")
    assert [line for line in text.splitlines() if line] == [
        "M = 2 * 3", "def run(a, b, i):", "    s = cuda.local.array(2 * M, FT)",
        "    s[mul_rn(i, 2)] = mul_rn(a, b) + mul_rn(a, mul_rn(b, a))",
        "    s[0] = mul_rn(s[0], a - b)"]
    net = kernel_netlist(_one_mass())
    co = coefficient_arrays(net, "float64")
    opts = gpu.options(net, None, "rk4", "float64", co, 1, reductions.plan([], net), fma=False)
    kernel = cudagen.generate(net, opts)
    assert "from springc.kernels.cudamul import mul_rn" in kernel
    body = kernel.split("def run(", 1)[1]
    assert "mul_rn(bm0, v[0])" in body and " * " not in body
    assert cudagen.generate(net, gpu.options(net, None, "rk4", "float64", co, 1,
                                             reductions.plan([], net))).count("mul_rn") == 0
    assert 'fastmath=False' in codegen.decorator(fma=False)
    assert 'fastmath={"contract"}' in codegen.decorator()


def test_unfused_cpu_kernels_give_the_bits_of_the_simulated_cuda_form(tmp_path):
    """The stiff block with no product fused (`fma` False), float64 and float32: the CPU
    kernels compiled by numba against the CUDA form run by numba's simulator, which does
    each IEEE operation on its own as NumPy's scalars do. Equal to the bit; with LLVM's
    contraction (the default) this block's float32 probes move by about 2e-4
    (docs/bench-gpu.md#fused-multiply-add), more than the issue's 1e-5 between devices."""
    out = tmp_path / "rounding.json"
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    env.pop("NUMBA_DISABLE_JIT", None)
    proc = subprocess.run([sys.executable, str(SCRIPT), "rounding", "--json", str(out)],
                          env=env, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.exists(), proc.stdout + proc.stderr
    cases = json.loads(out.read_text())
    assert [c["precision"] for c in cases] == ["float64", "float32"]
    for case in cases:
        assert set(case["errors"]) == {"x(s0)", "x(s23)", "energy"}
        assert case["worst"] == 0.0, case
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_strang_splitting_is_refused():
    gpu.require(_one_mass(), "exp-rk4")  # a Lawson scheme runs
    with pytest.raises(UsageError, match="Runge-Kutta tableaux and the Lawson schemes"):
        gpu.require(_one_mass(), "strang-rk4")


@NO_GPU
def test_device_cuda_without_a_gpu_exits_1_with_the_reason(tmp_path):
    spr = tmp_path / "osc.spr"
    spr.write_text("Ma a m=1 b=3\nKa a k=100\n.probe x(a)\n.tran 1e-3 0.01\n")
    res = CliRunner().invoke(main, ["sim", str(spr), "-o", str(tmp_path / "x.npz"),
                                    "--method", "rk4", "--substeps", "1", "--device", "cuda"])
    assert res.exit_code == 1, res.output
    assert "--device cuda: no CUDA GPU is available here" in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "x.npz").exists()


@NO_GPU
def test_auto_is_the_cpu_without_a_gpu():
    assert gpu.resolve("auto") == "cpu"
    assert gpu.resolve("cpu") == "cpu"
    with pytest.raises(UsageError, match="unknown device"):
        gpu.resolve("tpu")


def test_auto_runs_on_the_cpu_what_the_cuda_form_does_not(monkeypatch):
    """With a GPU, `auto` still takes the CPU for Strang splitting or thermal noise (`cuda`
    refuses them): the run equals the plain CPU run."""
    import numpy as np

    import springc

    net = springc.load("Ma a m=1 b=3\nKa a k=100\nFa a in(0)\n.probe x(a)\n.tran 1e-3 0.02\n")
    assert not gpu.serves(net.flat, "strang-rk4") and gpu.serves(net.flat, "exp-rk4")
    u = np.ones((2, 1, 21))
    cpu = net.simulate(u, method="strang-rk4", substeps=1)
    monkeypatch.setattr(gpu, "resolve", lambda device: "cuda")
    auto = net.simulate(u, method="strang-rk4", substeps=1, device="auto")
    np.testing.assert_array_equal(auto["x(a)"], cpu["x(a)"])
    with pytest.raises(UsageError, match="Runge-Kutta tableaux and the Lawson schemes"):
        net.simulate(u, method="strang-rk4", substeps=1, device="cuda")


@NO_GPU
@pytest.mark.parametrize("args", [["train", "--data", "D", "-o", "M"], ["eval", "M"],
                                  ["classify", "M", "a.wav"], ["cv", "--data", "D", "-o", "O"]])
def test_kws_commands_take_device_cuda_without_a_gpu_as_a_user_error(args):
    """--device on the commands that simulate data sets: cuda without a GPU exits 1 with the
    reason before any work."""
    res = CliRunner().invoke(main, args + ["--device", "cuda"])
    assert res.exit_code == 1, res.output
    assert "--device cuda: no CUDA GPU is available here" in res.output
    assert "Traceback" not in res.output


@NO_GPU
def test_default_device_resolves_nests_and_restores():
    assert gpu.current() == "cpu"
    with gpu.default_device("auto") as outer:
        assert outer == gpu.current() == "cpu"
        with pytest.raises(UsageError, match="no CUDA GPU"):
            with gpu.default_device("cuda"):
                pass
        assert gpu.current() == "cpu"
    assert gpu.current() == "cpu"


def test_data_set_batches_run_in_this_process_on_the_gpu(monkeypatch):
    """Inside default_device('cuda') the batches are not sent to Dask workers (the GPU is this
    process's) and no cluster starts."""
    from springc.kws.features import distributed

    monkeypatch.setattr(gpu, "_DEFAULT", ["cpu", "cuda"])
    monkeypatch.setattr(distributed, "_client", lambda *a: pytest.fail("a cluster started"))
    with distributed.session(None, 2):
        got = distributed.map_batches(lambda b: (os.getpid(), sum(b)), [[1, 2], [3], [4, 5]],
                                      workers=2)
    assert got == [(os.getpid(), 3), (os.getpid(), 3), (os.getpid(), 9)]



def test_lanes_of_a_population_stay_on_the_cpu_under_the_gpu_default(monkeypatch):
    """`simulate_lanes` (a population's devices in the lanes of one call, `springc eval --mc`)
    inside default_device('cuda'): the CUDA form takes no per-run coefficients, so the call
    runs on the CPU, as it does without a GPU, instead of being refused."""
    import numpy as np

    import springc
    from springc.sim.simulate import simulate_lanes

    text = "Ma a m=1 b=3\nKa a k={k}\nFa a in(0)\n.probe x(a)\n.tran 1e-3 0.02\n"
    members = [springc.load(text.format(k=k)).checked for k in (100.0, 120.0)]
    u = np.ones((1, 1, 21))
    cpu = simulate_lanes(members, ["soft", "stiff"], u, method="rk4", substeps=1)
    monkeypatch.setattr(gpu, "_DEFAULT", ["cpu", "cuda"])
    monkeypatch.setattr(gpu, "resolve", lambda device: "cpu" if device == "cpu" else "cuda")
    on_gpu = simulate_lanes(members, ["soft", "stiff"], u, method="rk4", substeps=1)
    np.testing.assert_array_equal(on_gpu.probes["x(a)"], cpu.probes["x(a)"])


@NO_GPU
def test_bench_on_cuda_without_a_gpu_exits_1_and_writes_nothing(tmp_path):
    out = tmp_path / "bench-out"
    res = CliRunner().invoke(main, ["bench", "--quick", "--case", "duffing", "--out", str(out),
                                    "--device", "cuda"])
    assert res.exit_code == 1, res.output
    assert "--device cuda: no CUDA GPU is available here" in res.output
    assert "Traceback" not in res.output
    assert not out.exists()


def test_bench_page_names_the_device_springcs_kernels_ran_on():
    """`springc bench --device cuda` records the GPU; a CPU run's page (and the stored
    bench.json of runs before the option, which has no device) says nothing of it."""
    from springc.bench import report

    machine = {"when": "2026-11-27 20:00:00", "cpus": 16, "load": 0.1}
    cpu = report._lead([], machine)
    assert report._lead([], {**machine, "device": "cpu"}) == cpu
    gpu_page = report._lead([], {**machine, "device": "NVIDIA H200"})
    assert "springc's kernels in the CUDA form on NVIDIA H200 (the peers" in gpu_page
    assert gpu_page.replace(report._device_md({"device": "NVIDIA H200"}), "") == cpu
    with gpu.default_device("cpu"):
        assert gpu.device_name() == "cpu"


def test_layout_changes_from_the_scripts_options_and_environment(monkeypatch):
    """The measuring scripts' `--threads` and SPRINGC_SLOT_MAX / SPRINGC_MAX_REGISTERS as
    `gpu.layout` changes, which apply inside the block only."""
    assert gpu.split_threads(1) == {"split_min": 10**9}
    assert gpu.split_threads(0) == gpu.split_threads(None) == {"split_threads": None}
    assert gpu.split_threads(64) == {"split_threads": 64}
    monkeypatch.setenv("SPRINGC_SLOT_MAX", "2")
    monkeypatch.setenv("SPRINGC_MAX_REGISTERS", "0")
    assert gpu.env_layout() == {"slot_max": 2}
    monkeypatch.setenv("SPRINGC_MAX_REGISTERS", "96")
    default = gpu.current_layout()
    with gpu.layout(**gpu.env_layout(), **gpu.split_threads(64)):
        inside = gpu.current_layout()
        with gpu.layout(25, slot_max=3):
            assert gpu.current_layout().slot_max == 3 and gpu.steps_per_call() == 25
            assert gpu.current_layout().split_threads == 64  # the outer block's
    assert (inside.slot_max, inside.max_registers, inside.split_threads) == (2, 96, 64)
    assert gpu.current_layout() == default and gpu.steps_per_call() == gpu.STEPS_PER_CALL
