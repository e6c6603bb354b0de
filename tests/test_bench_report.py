"""springc.bench.report: the page's first screen (one table per case with its plot, then the
must-show verdicts, then how it was measured), the same page again from a stored bench.json,
and the render command's errors. The cases are synthetic, with given errors and wall times."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import pytest
from click.testing import CliRunner
from springc_cli.main import main as cli

from springc.bench import report
from springc.bench.suite import CaseResult, Row

RUNS, TSTOP, STRETCH = 2, 1.0, 0.005
MACHINE = {"cpus": 2, "load": 2.5, "when": "2026-01-02 03:04:05", "suite_wall_s": 600.0}
HEAD = ("| method | substeps | precision | error, whole run | error, first 5 ms | wall s | "
        "throughput run-s/s | vs DOP853 | vs ngspice |")
SPRINGC = shutil.which("springc") or str(Path(sys.executable).with_name("springc"))


def _kernel(method: str, sub: int, err: float, wall_per_run_s: float,
            precision: str = "float64", recorded: bool = True) -> Row:
    """A kernel call of RUNS runs of TSTOP s: wall = RUNS * TSTOP * wall per run-second."""
    wall = RUNS * TSTOP * wall_per_run_s
    errors = {"x(a)": err / 2, "x(b)": err} if recorded else {}
    return Row(f"kernel {method}", method, sub, precision, errors, wall, 1.5, RUNS * TSTOP,
               RUNS * TSTOP / wall, ceiling_fraction=0.8, peak_fraction=0.4,
               stretch_errors=dict(errors), recorded=recorded)


def _diverged(method: str, sub: int) -> Row:
    return Row(f"kernel {method}", method, sub, "float64", {}, math.nan, 1.5, 0.0, 0.0,
               note="stopped by the divergence guard: run run0 diverged by t = 0.01 s")


def _peer(method: str, err: float, wall_per_run_s: float) -> Row:
    return Row(f"peer {method}", method, 1, "float64", {"x(b)": err}, wall_per_run_s * STRETCH,
               0.0, STRETCH, 1 / wall_per_run_s, stretch_errors={"x(b)": err})


def _case(name: str, rows: list[Row], floor: float = 1e-14) -> CaseResult:
    ref = {"method": "rk4", "substeps": 64, "estimate": {"x(b)": floor / 2},
           "stretch_estimate": {"x(b)": floor / 2}, "check": {"x(b)": floor},
           "check_tstop": STRETCH, "check_rtol": 1e-12, "wall_s": 3.0, "check_wall_s": 4.0,
           "floor": floor}
    return CaseResult(name, f"the {name} network", 24, RUNS, 1 / 32000, TSTOP, rows,
                      ceiling={"float64": 100.0}, peak={"float64": 200.0},
                      peer_tstop=STRETCH, reference=ref, ladder_note="every peer's error "
                      "reached (reached: DOP853, ngspice)", skipped={"RK45": "not wanted here"})


def _results() -> list[CaseResult]:
    feature = _case("feature", [
        _kernel("rk4", 1, 0.5, 0.004), _kernel("rk4", 2, 0.04, 0.008),
        _kernel("exp-rk4", 16, 1e-12, 0.08), _kernel("exp-rk4", 1, 1e-4, 0.005),
        _kernel("rk4", 1, 0.5, 0.003, precision="float32"), _diverged("exp-heun3", 1),
        _kernel("rk4", 1, 0.0, 0.002, recorded=False),
        _peer("DOP853", 2e-11, 500.0), _peer("ngspice", 1e-4, 8000.0)])
    delay = _case("delay", [_kernel("rk4", 1, 1e-6, 0.01), _peer("DOP853", 1e-13, 500.0),
                            _peer("ngspice", 1e-3, 50.0)])
    return [feature, delay]


@pytest.fixture
def stored(tmp_path) -> Path:
    """A bench.json as `springc bench` writes it (machine, cases; its claims left out: the
    page computes them from the rows)."""
    path = tmp_path / "stored.json"
    path.write_text(json.dumps({"machine": MACHINE,
                                "cases": [asdict(r) for r in _results()]}, indent=1))
    return path


def _page(tmp_path, stored) -> str:
    return report.render(stored, tmp_path / "out")["md"].read_text()


def test_the_page_opens_with_one_table_per_case_then_the_verdicts_then_the_method(
        tmp_path, stored):
    md = _page(tmp_path, stored)
    order = ["## feature: the feature network", "## delay: the delay network",
             "## The targets: met or missed", "## How it was measured",
             "### Every figure in full", "### feature in full", "### delay in full"]
    at = [md.index(h + "\n") for h in order]
    assert at == sorted(at)
    first = md[:at[2]]
    assert first.count("| method |") == 2 and first.count(HEAD + "\n") == 2
    assert "Plot: [speed against error](bench/feature.png)." in first
    assert "Plot: [speed against error](bench/delay.png)." in first
    assert "Not run here: RK45 (not wanted here)." in first
    assert "load average 2.5 at the start; the suite took 10.0 min" in first
    assert f"`{report.RENDER_COMMAND}`" in first
    # the machine was busy (load at least half its CPUs): the method section says so
    assert "The machine was busy with other work while the suite ran" in md[at[3]:]


def test_the_table_rates_each_row_against_each_peer_at_equal_error(tmp_path, stored):
    table = _page(tmp_path, stored).split("## delay")[0].splitlines()
    rows = {tuple(c.strip() for c in line.split("|")[1:4]): line for line in table
            if line.startswith("| ") and not line.startswith("| method")}
    # rk4 x1 (0.5) is less accurate than both peers; exp-rk4 x1 (1e-4) reaches ngspice's 1e-4
    # at 8000 / 0.005 and is the cheapest that does; exp-rk4 x16 (1e-12) reaches DOP853's
    # 2e-11 at 500 / 0.08 = 6250x (the cheapest) and ngspice's at 8000 / 0.08
    assert rows[("rk4", "1", "float64")] == (
        "| rk4 | 1 | float64 | 0.5 | 0.5 | 0.008 | 250 | - | - |")
    assert rows[("exp-rk4", "1", "float64")].endswith("| 0.0001 | 0.0001 | 0.01 | 200 | - | "
                                                      "**1600000x** |")
    assert rows[("exp-rk4", "16", "float64")].endswith("| **6250x** | 100000x |")
    assert rows[("exp-heun3", "1", "float64")] == (
        "| exp-heun3 | 1 | float64 | diverged | diverged | - | - | - | - |")
    assert rows[("DOP853 (peer)", "-", "float64")] == (
        "| DOP853 (peer) | - | float64 | - | 2e-11 | 2.5 | 0.002 | - | - |")
    # grouped by method and precision, by substeps within a group; no timing-only rows
    names = [k for k in rows]
    assert names[:5] == [("rk4", "1", "float64"), ("rk4", "2", "float64"),
                         ("exp-rk4", "1", "float64"), ("exp-rk4", "16", "float64"),
                         ("rk4", "1", "float32")]
    assert len(names) == 8  # 6 recorded kernel rows and 2 peers
    # the timing-only row is in the case's detail table, with every column
    md = _page(tmp_path, stored)
    assert "| rk4 x1 float64, no probes | - | - | 0.004 | 1.50 |" in md.split("### feature in")[1]


def test_the_verdicts_are_one_line_each_with_their_figures(tmp_path, stored):
    md = _page(tmp_path, stored)
    block = md.split("## The targets: met or missed\n\n")[1].split("\n\n")[0]
    lines = block.splitlines()
    assert len(lines) == 5 and all(line.startswith("- **") for line in lines)
    # 0.01 / 0.008 = 1.25x RK4 x1's wall; float32 has no row within 1e-3
    assert lines[0] == ("- **PARTLY MET (1 of 2)**: Feature extractor: every probe within 1e-3 "
                        "of the reference at no more than 1.5x the wall time of classic RK4 at "
                        "32 kHz: float64 1.25x with exp-rk4 x1 float64; float32: no row within "
                        "1e-3 (missed).")
    assert lines[1].endswith(": feature float64 80%; feature float32 80%; delay float64 80%.")
    assert lines[2].startswith("- **PARTLY MET (1 of 2)**: At least 300x faster than scipy")
    # delay: rk4 x1 at 1e-6 is 50000x faster; x64 would reach 1e-13, 50000 / 64 = 781x
    assert lines[2].endswith("feature 6250x; delay missed: no measured row as accurate "
                             "(predicted, not measured: 781x at rk4 x64 float64).")
    assert lines[3].startswith("- **NOT MEASURED**: At least 300x faster than DOP853 rtol 1e-6 "
                               "held to max_step tstep/8")
    assert lines[3].endswith(": feature not run; delay not run.")
    assert lines[4].startswith("- **MET**: At least 50x faster than ngspice")
    assert lines[4].endswith(": feature 1600000x; delay 5000x.")


def test_rendering_is_deterministic_and_idempotent_in_place(tmp_path, stored):
    one = report.render(stored, tmp_path / "one")
    two = report.render(stored, tmp_path / "two")
    assert set(one) == {"md", "json", "feature", "delay"}
    assert one["feature"] == tmp_path / "one" / "bench" / "feature.png"
    for key in one:
        assert one[key].read_bytes() == two[key].read_bytes(), key
    # the documented command renders the stored json into the folder that holds it
    before = {key: path.read_bytes() for key, path in one.items()}
    again = report.render(one["json"], tmp_path / "one")
    assert {key: path.read_bytes() for key, path in again.items()} == before
    data = json.loads(one["json"].read_text())
    assert data["claims"]["speedups"]["feature"][0]["floor_limited"] is False


@pytest.mark.parametrize("content, reason", [
    (None, "no such file"),
    ('{"cases": [', "not valid JSON (Expecting value at line 1, column 12)"),
    ('{"machine": {}}', "not a bench.json of `springc bench` (no 'cases')"),
    ('{"machine": {}, "cases": [{"name": "x", "rows": [{"name": 1}]}]}',
     "not a bench.json of `springc bench`"),
])
def test_render_of_a_missing_or_garbled_file_names_it_and_exits_1(tmp_path, content, reason):
    path = tmp_path / "bench.json"
    if content is not None:
        path.write_text(content)
    out = tmp_path / "out"
    got = CliRunner().invoke(cli, ["bench", "--render", str(path), "--out", str(out)])
    assert got.exit_code == 1, got.output
    assert f"error: {path}: {reason}" in got.output
    assert "Traceback" not in got.output and not out.exists()


def test_the_installed_command_refuses_a_folder_without_a_traceback(tmp_path):
    got = subprocess.run([SPRINGC, "bench", "--render", str(tmp_path), "--out",
                          str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert got.returncode == 1
    assert got.stderr.strip() == f"error: {tmp_path}: is a folder; give the bench.json file"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("start, end, busy", [(0.3, None, False), (0.3, 0.9, False),
                                              (0.3, 1.0, True), (2.5, None, True)])
def test_the_method_section_says_when_the_machine_was_busy(start, end, busy):
    """Busy: a load average of half the CPUs or more at the start or at the end."""
    machine = {"cpus": 2, "load": start, "when": "then"} | ({"load_end": end} if end else {})
    text = report._machine_md(machine)
    assert text.startswith(f"Machine: 2 CPU(s) available, load average {start} at the start"
                           + (f" and {end} at the end, then." if end else ", then."))
    assert ("The machine was busy with other work" in text) == busy


def test_the_committed_page_is_its_stored_numbers_rendered(tmp_path):
    """docs/bench.md is `springc bench --render docs/bench/bench.json --out docs` of the
    committed numbers: run that after changing the report (the PNGs beside it depend on the
    matplotlib version, so only their presence is checked)."""
    docs = Path(__file__).resolve().parents[1] / "docs"
    got = report.render(docs / "bench" / "bench.json", tmp_path)
    assert got["md"].read_text() == (docs / "bench.md").read_text()
    assert got["json"].read_text() == (docs / "bench" / "bench.json").read_text()
    for name in set(got) - {"md", "json"}:
        assert (docs / "bench" / f"{name}.png").is_file(), name
        assert f"]({report.SUBDIR}/{name}.png)" in got["md"].read_text()
