"""docs/results-trim.md's writer: a report of `eval --trim --json` becomes its row with
every figure as measured, the table is ordered by size and spread, the page's own reading
survives a regeneration, and the plot is written beside the page."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.device_page import READING
from springc.kws.evaluation.trim_page import row, write_page


def report(spread: float, untrimmed: list[float], trimmed: list[float]) -> dict:
    """An `eval --mc --trim --json` report of devices with these accuracies."""
    def summary(values: list[float]) -> dict:
        return {"mean": sum(values) / len(values), "stderr": 0.01, "sd": 0.02, "p5": 0.0,
                "worst": min(values)}

    devices = [{"device": k, "accuracy": u, "trimmed": t, "diverged": False,
                "decision_error": 0.1} for k, (u, t) in enumerate(zip(untrimmed, trimmed))]
    return {"devices": devices, "nominal": 0.5, "nominal_trimmed": 0.52,
            "nominal_priors": [100.0],
            "accuracy": summary(untrimmed), "trimmed": summary(trimmed), "n": 48,
            "trim_clips": 48, "spread": spread, "kind": "local", "stage": "all", "seed": 0}


def test_each_report_reaches_its_row_and_the_plot(tmp_path: Path) -> None:
    rows = [row("8x3", report(0.03, [0.25, 0.35], [0.4, 0.44])),
            row("8x3", report(0.01, [0.5, 0.46], [0.5, 0.5]))]
    text = write_page(rows, tmp_path / "page.md", intro="").read_text()
    # gain per device 15 and 9 points: mean 12.0, standard error 3.0
    assert "| 8x3 | 0.03 | 2 | 50.0 | 52.0 | 30.0 +- 1.0 | 42.0 +- 1.0 | 25.0 | 40.0 | " \
           "+12.0 +- 3.0 |" in text
    assert "| 8x3 | 0.01 | 2 | 50.0 | 52.0 | 48.0 +- 1.0 | 50.0 +- 1.0 | 46.0 | 50.0 | " \
           "+2.0 +- 2.0 |" in text
    assert text.index("| 8x3 | 0.01 |") < text.index("| 8x3 | 0.03 |")
    assert (tmp_path / "page.png").stat().st_size > 0


def test_reading_survives_regeneration(tmp_path: Path) -> None:
    md = tmp_path / "page.md"
    rows = [row("4x2", report(0.01, [0.4], [0.45]))]
    write_page(rows, md, intro=f"{READING}\n\nTrimming helps.\n")
    write_page(rows, md)
    text = md.read_text()
    assert text.count(READING) == 1 and "Trimming helps." in text


def test_a_stage_spread_alone_reaches_the_stage_table(tmp_path: Path) -> None:
    """A report of `eval --mc --stage delays` (no trim) is a row of the stage table beside
    the trimmed report's every-stage row of the same size and spread; the trim table and
    the plot take only trimmed rows."""
    stage = report(0.03, [0.3, 0.32], [0.3, 0.32])
    del stage["trimmed"], stage["trim_clips"], stage["nominal_trimmed"]
    stage["stage"] = "delays"
    rows = [row("4x2", stage), row("4x2", report(0.03, [0.25, 0.29], [0.27, 0.31]))]
    text = write_page(rows, tmp_path / "page.md", intro="").read_text()
    assert "| 4x2 | 0.03 | delays | 31.0 +- 1.0 | 30.0 | 19.0 |" in text
    assert "| 4x2 | 0.03 | all | 27.0 +- 1.0 | 25.0 | 23.0 |" in text
    assert text.index("| 4x2 | 0.03 | delays |") < text.index("| 4x2 | 0.03 | all |")
    assert text.count("| 4x2 | 0.03 | 2 |") == 1  # the trim table: the trimmed row alone
