"""`springc bench --startup`'s rows: each keyword-spotting row simulates as much as it feeds
(the input's length, not the netlist's .tran), and a row's summary is the median and range of
what was measured."""

from __future__ import annotations

from pathlib import Path

import soundfile as sf

from springc.bench.startup import INPUT_S, Row, rows


def test_keyword_spotting_rows_simulate_their_input(tmp_path: Path) -> None:
    sims = [r for r in rows(tmp_path) if r.name.startswith("sim ") and "-i" in r.argv]
    assert len(sims) == 2
    for row in sims:
        wav = Path(row.argv[row.argv.index("-i") + 1])
        info = sf.info(wav)
        # samples at 0, h, ..., INPUT_S: one more than INPUT_S / h
        assert (info.frames - 1) / info.samplerate == INPUT_S
        assert float(row.argv[row.argv.index("--tstop") + 1]) == INPUT_S


def test_summary_is_median_and_range() -> None:
    row = Row("x", ["true"], warm=[1.0, 3.0, 2.0])
    assert row.summary("warm") == "2.00 (1.00-3.00)"
    assert row.summary("cold") == "-"
