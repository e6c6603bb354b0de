"""`springc bench --startup`: a netlist's first result as a user meets it.

Whole `springc` processes, timed from their start to their exit, several runs of each:
`build` and `sim` of the example netlists, of the 564-dof keyword-spotting-sized network
(`networks.kws_network`) and of the 8x3 classifier (`networks.pipeline_classifier`, 788
masses) on 0.25 s of speech-like input, warm (the kernel cache filled by one unmeasured run
first) and cold (an empty `SPRINGC_CACHE` for every run). Beside them, in the same run:
`python -c "import numba"` (the floor of a process that compiles with numba), a process
that calls one small numba function loaded from numba's own cache (the floor of any warm
numba kernel: numba readies its compiler to load one), and ngspice's batch run of each
example netlist (`springc export --spice`), where ngspice is installed.
Writes bench-startup.md and bench/startup.json.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

COMMAND = "springc bench --startup --out docs"
EXAMPLES = Path(__file__).resolve().parents[2] / "netlists" / "examples"
INPUT_S = 0.25  # seconds of input for the keyword-spotting networks
RUNS = 5  # measured runs per warm row
COLD_RUNS = 3  # measured runs per cold row (each compiles every kernel it needs)


@dataclass
class Row:
    """One command line and its wall times (s), warm and cold."""

    name: str
    argv: list[str]
    what: str = ""
    warm: list[float] = field(default_factory=list)
    cold: list[float] = field(default_factory=list)

    def summary(self, which: str) -> str:
        """'median (min-max)' of the warm or cold times, '-' where none were taken."""
        times = getattr(self, which)
        if not times:
            return "-"
        return f"{statistics.median(times):.2f} ({min(times):.2f}-{max(times):.2f})"


def springc_argv(*args: str) -> list[str]:
    """The installed `springc` command beside this Python, with `args`."""
    return [str(Path(sys.executable).with_name("springc")), *args]


def write_inputs(folder: Path) -> dict[str, Path]:
    """The netlists and input files of the keyword-spotting rows, in `folder`."""
    import soundfile as sf

    from springc.bench import networks
    from springc.bench.suite import SPEECH_LEVEL, speech_like
    from springc.design.scale import flat_text
    from springc.kws.features.massspring import INPUT_RATE

    kws = networks.kws_network()
    kws_rate = round(1 / kws.tran.tstep)
    classifier = networks.pipeline_classifier()
    paths = {"kws": folder / "kws564.spr", "classifier": folder / "classifier8x3.spr",
             "kws_in": folder / "kws564.wav", "classifier_in": folder / "classifier.wav"}
    paths["kws"].write_text(flat_text(kws, "564-dof keyword-spotting-sized network"))
    paths["classifier"].write_text(flat_text(classifier, "8x3 classifier, 12 heads"))
    for key, rate in (("kws_in", kws_rate), ("classifier_in", INPUT_RATE)):
        signal = SPEECH_LEVEL * speech_like(INPUT_S, rate, 1, seed=5)[0, 0]
        sf.write(paths[key], signal, int(rate), subtype="FLOAT")
    return paths


def rows(folder: Path) -> list[Row]:
    """Every measured command line (files written to `folder`)."""
    out = [Row("import numba", [sys.executable, "-c", "import numba"], "the floor"),
           Row("numba cached function", [sys.executable, str(numba_floor(folder))],
               "one small function loaded from numba's cache as numba loads it (its "
               "lowering registries first; springc's kernels load without them)")]
    for path in sorted(EXAMPLES.glob("*.spr")):
        out.append(Row(f"build {path.name}", springc_argv("build", str(path))))
        out.append(Row(f"sim {path.name}", springc_argv("sim", str(path), "-o",
                                                        str(folder / "out.npz")),
                       "integration chosen for 1e-3"))
    return out + keyword_rows(write_inputs(folder), folder)


NUMBA_FLOOR = """import numpy as np
from numba import njit


@njit(cache=True)
def total(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i]
    return s


total(np.ones(3))
"""


def numba_floor(folder: Path) -> Path:
    """A script that calls one small `cache=True` numba function (cached beside it by the
    row's unmeasured first run)."""
    path = folder / "numba_floor.py"
    path.write_text(NUMBA_FLOOR)
    return path


def keyword_rows(files: dict[str, Path], folder: Path) -> list[Row]:
    """build and sim of the keyword-spotting networks `write_inputs` wrote, each sim over
    the input's INPUT_S seconds."""
    out = []
    # the classifier's compressors stiffen at this level: exp-rk4 x2 diverges, x4 does not
    for key, method, sub, what in (("kws", "rk4", 2, "564 dofs"),
                                   ("classifier", "exp-rk4", 4, "788 dofs")):
        spr, wav = str(files[key]), str(files[f"{key}_in"])
        out.append(Row(f"build {files[key].name}", springc_argv("build", spr), what))
        out.append(Row(f"sim {files[key].name}", springc_argv(
            "sim", spr, "-i", wav, "-o", str(folder / "out.npz"), "--method", method,
            "--substeps", str(sub), "--tstop", f"{INPUT_S:g}"),
            f"{what}, {INPUT_S:g} s of input simulated, {method} x{sub}"))
    return out


def ngspice_rows(folder: Path) -> list[Row]:
    """ngspice in batch mode on each example netlist's export (none without ngspice)."""
    if shutil.which("ngspice") is None:
        return []
    out = []
    for path in sorted(EXAMPLES.glob("*.spr")):
        circuit = folder / f"{path.stem}.cir"
        done = subprocess.run(springc_argv("export", "--spice", str(path), "-o", str(circuit)),
                              capture_output=True)
        if done.returncode == 0:
            out.append(Row(f"ngspice {path.stem}.cir", ["ngspice", "-b", str(circuit)],
                           "the same netlist, exported"))
    return out


def timed(argv: list[str], env: dict[str, str], cwd: Path) -> float:
    """Wall seconds of one process run in `cwd` (ngspice writes its probes there), from its
    start to its exit; it must succeed."""
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed:\n{done.stdout}{done.stderr}")
    return wall


def measure(row: Row, runs: int, cold_runs: int, cache: Path) -> None:
    """Fill the row's warm times (cache `cache`, filled first) and cold times (an empty
    cache per run)."""
    env, cwd = {**os.environ, "SPRINGC_CACHE": str(cache)}, cache.parent
    timed(row.argv, env, cwd)
    row.warm = [timed(row.argv, env, cwd) for _ in range(runs)]
    for _ in range(cold_runs):
        with tempfile.TemporaryDirectory() as empty:
            row.cold.append(timed(row.argv, {**os.environ, "SPRINGC_CACHE": empty}, cwd))


def run_startup(runs: int = RUNS, cold_runs: int = COLD_RUNS,
                progress: Callable[[str], None] = print) -> dict:
    """Measure every row; returns the result for `write_report`."""
    from springc.bench.suite import machine_info

    machine = machine_info()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        table = rows(folder) + ngspice_rows(folder)
        for row in table:
            cold = cold_runs if row.name.split()[0] in ("build", "sim") else 0
            progress(f"{row.name}: {runs} warm, {cold} cold runs")
            measure(row, runs, cold, folder / "cache")
    machine["load_end"] = machine_info()["load"]
    return {"machine": machine, "rows": [asdict(r) for r in table],
            "python": sys.version.split()[0], "numpy": np.__version__}


def markdown(result: dict) -> str:
    """The page: a table of every row, warm and cold, then how it was measured."""
    from springc.bench.suite import of_cpu

    m = result["machine"]
    lines = ["# A netlist's first result: start-up, checks and kernel loading", "",
             "| command | what | warm: median (min-max), s | cold: median (min-max), s |",
             "|---|---|---|---|"]
    for raw in result["rows"]:
        row = Row(**raw)
        lines.append(f"| `{row.name}` | {row.what} | {row.summary('warm')} | "
                     f"{row.summary('cold')} |")
    lines += ["", "## How it was measured", "",
              f"- {m['when']}, {m['cpus']} CPUs{of_cpu(m)}, load average {m['load']} at the "
              f"start and {m['load_end']} at the end; Python {result['python']}, numpy "
              f"{result['numpy']}.",
              f"- `{COMMAND}`: whole processes timed from start to exit; warm rows after one "
              f"unmeasured run filled the kernel cache, cold rows each with an empty "
              "`SPRINGC_CACHE` (numba compiles every kernel the command needs).",
              f"- The keyword-spotting rows simulate {INPUT_S:g} s (`--tstop`) of "
              "speech-like input from a float WAV file at the netlist's own rate (no "
              "resampling)."]
    return "\n".join(lines) + "\n"


def write_report(result: dict, outdir: Path) -> dict[str, Path]:
    """OUTDIR/bench-startup.md and OUTDIR/bench/startup.json."""
    (outdir / "bench").mkdir(parents=True, exist_ok=True)
    md = outdir / "bench-startup.md"
    data = outdir / "bench" / "startup.json"
    data.write_text(json.dumps(result, indent=1) + "\n")
    md.write_text(markdown(result))
    return {"md": md, "json": data}
