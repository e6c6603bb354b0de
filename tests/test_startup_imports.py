"""What `springc build` and `springc sim` import, run again on an unchanged netlist (a warm
cache): only what they use. Measured as a user meets it, whole processes with Python's
`-X importtime`; a module in a command's forbidden list fails the test with the chain that
imported it.

`build` of a netlist checked before reads its check from the cache (springc.check.store):
no parser, no scipy, no numba. `sim` needs numba to load its kernel, and loads it without
numba's lowering registries (`loader.load_first`), which would import cffi, scipy's BLAS
module and numba's own array, linear algebra, random and polynomial libraries;
nothing else heavy. The kernel so loaded gives the bits of the one compiled."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


ROOT = Path(__file__).resolve().parents[1]
DUFFING = ROOT / "netlists" / "examples" / "duffing.spr"
HEAVY = ("numba", "llvmlite", "scipy", "lark", "matplotlib", "sklearn", "dask", "distributed",
         "xarray", "soundfile", "pandas", "cffi", "tqdm")
ALLOWED = {
    "build": (),
    "sim": ("numba", "llvmlite", "scipy"),  # scipy: its package alone, by numba's import
}
# numba's lowering registries, which only compiling reads (`loader.load_first`)
REGISTRIES = ("numba.np.arraymath", "numba.np.linalg", "numba.np.random", "numba.np.polynomial",
              "numba.core.typing.cffi_utils")
NEVER = ("cffi", "scipy.linalg", "scipy.signal", "scipy.optimize", "scipy.stats",
         "scipy.integrate", "scipy.ndimage")


def imported(args: list[str]) -> dict[str, str]:
    """{module: the module that imported it} of one `springc` process (`-X importtime`)."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "springc_cli.main", *args],
                          capture_output=True, text=True, env=os.environ.copy())
    assert done.returncode == 0, done.stdout + done.stderr
    out, stack = {}, []
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("import time:")]
    for line in reversed(lines):  # importtime prints a module after what it imported
        name = line.split("|")[-1]
        depth = (len(name) - len(name.lstrip())) // 2
        name = name.strip()
        del stack[depth:]
        out[name] = stack[-1] if stack else "(top)"
        stack.append(name)
    return out


@pytest.mark.parametrize("command", ["build", "sim"])
def test_a_warm_command_imports_only_what_it_uses(command: str, tmp_path: Path) -> None:
    args = [command, str(DUFFING)] + (["-o", str(tmp_path / "out.npz")] if command == "sim"
                                      else [])
    imported(args)  # checks the netlist (and compiles the kernel) into the session's cache
    found = imported(args)
    heavy = {m: by for m, by in found.items() if m.split(".")[0] in HEAVY}
    extra = {m: by for m, by in heavy.items() if m.split(".")[0] not in ALLOWED[command]}
    assert not extra, f"springc {command} imported {sorted(extra)[:8]} (first by {extra}"
    never = {m: by for m, by in found.items() if m.startswith(NEVER + REGISTRIES)}
    assert not never, f"springc {command} imported {never}"


def test_a_kernel_loaded_without_numba_registries_gives_the_compiled_bits(tmp_path: Path) -> None:
    """The same `sim` in an empty cache (numba compiles, its registries set up) and again
    (the kernel loaded alone, `loader.load_first`): the same samples to the bit."""
    env = {**os.environ, "SPRINGC_CACHE": str(tmp_path / "cache")}
    outs = [tmp_path / "cold.npz", tmp_path / "warm.npz"]
    for out in outs:
        done = subprocess.run([sys.executable, "-m", "springc_cli.main", "sim", str(DUFFING),
                               "--temp", "300", "-o", str(out)], capture_output=True,
                              text=True, env=env)
        assert done.returncode == 0, done.stdout + done.stderr
    cold, warm = np.load(outs[0]), np.load(outs[1])
    assert cold.files == warm.files
    for key in cold.files:
        assert np.array_equal(cold[key], warm[key]), key
