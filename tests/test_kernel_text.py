"""`simulate.kernel_text`: the kernel `simulate` loads, generated without compiling or
running it (the CUDA form's without a GPU), and scripts/kernel_texts.py's comparison of two
trees' texts."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

import springc
from springc.errors import UsageError
from springc.kernels import loader
from springc.sim.simulate import kernel_text

ROOT = Path(__file__).resolve().parents[1]
DUFFING = ROOT / "netlists" / "examples" / "duffing.spr"


def test_the_text_is_the_kernel_simulate_loads():
    net = springc.load(DUFFING)
    res = net.simulate()  # the integrator springc chooses, as `springc sim duffing.spr`
    settings = res.settings
    text = kernel_text(net.checked, method=settings.method, substeps=settings.substeps)
    # by name (the digest of the text): a kernel loaded earlier in the process keeps its path
    assert Path(res.info["kernel"]).name == loader.kernel_path(text).name


def test_the_cuda_forms_text_needs_no_gpu_and_refuses_what_it_cannot_run():
    net = springc.load(DUFFING)
    text = kernel_text(net.checked, method="rk4", substeps=1, device="cuda")
    assert "@cuda.jit" in text and "def run(" in text
    with pytest.raises(UsageError, match="strang-rk4"):
        kernel_text(net.checked, method="strang-rk4", substeps=1, device="cuda")


def _script():
    path = ROOT / "scripts" / "kernel_texts.py"
    spec = importlib.util.spec_from_file_location("kernel_texts", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_script_reports_every_case_that_differs_or_exists_in_one_tree_only():
    old = {"a rk4": "h1", "b rk4": "h2", "c rk4": "error: X", "d rk4": "h4"}
    new = {"a rk4": "h1", "b rk4": "h3", "c rk4": "error: X", "e rk4": "h5"}
    rows = _script().compare(old, new, None)
    assert rows == ["- b rk4: h2 -> h3", "- d rk4: h4 -> missing", "- e rk4: missing -> h5"]
    assert _script().compare(old, new, "b ") == ["- b rk4: h2 -> h3"]
