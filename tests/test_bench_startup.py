"""`springc bench --startup`'s rows: each keyword-spotting row simulates as much as it feeds
(the input's length, not the netlist's .tran), and a row's summary is the median and range of
what was measured."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from springc.bench.startup import INPUT_S, Row, keyword_rows, numba_floor


def test_keyword_spotting_rows_simulate_their_input(tmp_path: Path) -> None:
    files = {key: tmp_path / name for key, name in (
        ("kws", "kws564.spr"), ("classifier", "classifier8x3.spr"),
        ("kws_in", "kws564.wav"), ("classifier_in", "classifier.wav"))}
    rows = keyword_rows(files, tmp_path)
    sims = [r for r in rows if r.name.startswith("sim ")]
    assert [r.name for r in sims] == ["sim kws564.spr", "sim classifier8x3.spr"]
    for row in sims:
        key = "kws" if "kws" in row.name else "classifier"
        assert row.argv[row.argv.index("-i") + 1] == str(files[f"{key}_in"])
        assert float(row.argv[row.argv.index("--tstop") + 1]) == INPUT_S


def test_summary_is_median_and_range() -> None:
    row = Row("x", ["true"], warm=[1.0, 3.0, 2.0])
    assert row.summary("warm") == "2.00 (1.00-3.00)"
    assert row.summary("cold") == "-"


def test_numba_floor_row_loads_its_function_from_numbas_cache(tmp_path: Path) -> None:
    script = numba_floor(tmp_path)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # cache beside it
    for _ in range(2):  # the first run compiles and caches, the second loads
        subprocess.run([sys.executable, str(script)], check=True, cwd=tmp_path, env=env)
    assert list((tmp_path / "__pycache__").glob("numba_floor.total-*.nbi"))
