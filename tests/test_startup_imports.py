"""What `springc build` and `springc sim` import, run again on an unchanged netlist (a warm
cache): only what they use. Measured as a user meets it, whole processes with Python's
`-X importtime`; a module in a command's forbidden list fails the test with the chain that
imported it.

`build` of a netlist checked before reads its check from the cache (springc.check.store):
no parser, no scipy, no numba. `sim` needs numba to load its kernel; numba's registries import
cffi and scipy's BLAS module, which springc loads by itself (`loader.blas_module_alone`), not
through scipy.linalg's package; nothing else heavy."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from springc.kernels import loader

ROOT = Path(__file__).resolve().parents[1]
DUFFING = ROOT / "netlists" / "examples" / "duffing.spr"
HEAVY = ("numba", "llvmlite", "scipy", "lark", "matplotlib", "sklearn", "dask", "distributed",
         "xarray", "soundfile", "pandas", "cffi", "tqdm")
ALLOWED = {
    "build": (),
    "sim": ("numba", "llvmlite", "scipy", "cffi"),  # scipy: its BLAS module, for numba
}
NEVER = ("scipy.linalg", "scipy.signal", "scipy.optimize", "scipy.stats", "scipy.integrate",
         "scipy.ndimage")


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
    never = {m: by for m, by in found.items()
             if m.startswith(NEVER) and m != loader.BLAS_MODULE}  # that one loaded alone
    assert not never, f"springc {command} imported {never}"
