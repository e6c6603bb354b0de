"""docs/results-device.md's writer: every measured figure reaches its table as measured, the
page's own reading survives a regeneration, and the plot is written beside the page."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.device_page import READING, write_page

RESULTS = {
    "8x3 summing": {
        "accuracy": 0.61, "ideal": 0.61, "n": 136, "loss_db": 369.9, "train_s": 74.2,
        "seconds": 1187.0,
        "spread": [{"spread": 1e-3, "nominal": 0.5625, "mean": 0.568, "stderr": 0.005,
                    "worst": 0.5625}],
        "noise": [{"device_mass": 1e-40, "accuracy": 0.0833, "noiseless": 0.5625,
                   "decision_error": 12.5, "diverged": False}],
        "budget": {"stages": {"readouts": {"kt": 2.5e-35, "db_of_sound": -400.3}},
                   "bound_db": 52.9},
    },
    "8x3 zero-mode eps 1": {"accuracy": 0.60, "n": 136, "loss_db": 400.5},
    "unheard": {"engine": "flite",
                "eps 1": {"own": 0.684, "own_n": 136, "unheard": 0.526, "unheard_n": 346,
                          "loss_db": 400.7}},
}


def test_figures_reach_their_tables(tmp_path: Path) -> None:
    md = write_page(RESULTS, tmp_path / "page.md", intro="")
    text = md.read_text()
    assert "| 8x3 summing | 61.0 | 61.0 | 136 | 369.9 | 74 | 19.8 |" in text
    assert "| 8x3 zero-mode eps 1 | 60.0 | - | 136 | 400.5 | - | - |" in text
    assert "| 8x3 | summing | 0.001 | 56.2 | 56.8 +- 0.5 | 56.2 |" in text
    assert "| 8x3 | summing | 1e-40 | 8.3 | 56.2 | 12.5 |" in text
    assert "| 8x3 | summing | readouts | 2.5e-35 | -400.3 |" in text
    assert "| eps 1 | 68.4 (136) | 52.6 (346) | 400.7 |" in text
    # one spread point above the target: no threshold within the sweep; noise past it at once
    assert "| 8x3 summing | - | below 1e-40 |" in text
    assert (tmp_path / "page.png").stat().st_size > 1000


def test_reading_survives_regeneration(tmp_path: Path) -> None:
    md = tmp_path / "page.md"
    write_page(RESULTS, md, intro=f"{READING}\n\nThe summing heads hold.\n")
    write_page(RESULTS, md)
    text = md.read_text()
    assert text.count(READING) == 1 and "The summing heads hold." in text


def test_speaker_folds_reach_their_table(tmp_path: Path) -> None:
    """Each fold's accuracy and clips, the clip-weighted mean with the standard error of
    the folds' mean, the paired change and the devices' mean beside their nominal."""
    cv = {"fold0 zero-mode": {"accuracy": 0.50, "n": 100},
          "fold1 zero-mode": {"accuracy": 0.60, "n": 300},
          "fold0 summing": {"accuracy": 0.52, "n": 100,
                            "spread": {"mean": 0.55, "nominal": 0.56}},
          "fold1 summing": {"accuracy": 0.60, "n": 300,
                            "spread": {"mean": 0.57, "nominal": 0.58}}}
    text = write_page(RESULTS, tmp_path / "page.md", intro="", cv=cv).read_text()
    # zero-mode: (50*100 + 60*300)/400 = 57.5; folds' mean 55 +- sqrt(50/2)/... = 5.0
    assert "| zero-mode | 50.0 (100) | 60.0 (300) | 57.5 +- 5.0 | +0.0 +- 0.0 | - |" in text
    # summing: (52*100 + 60*300)/400 = 58.0, SE 4.0; change (2*100 + 0*300)/400 = +0.5, SE 1.0
    assert "| summing | 52.0 (100) | 60.0 (300) | 58.0 +- 4.0 | +0.5 +- 1.0 | 56.0 (57.0) |" in text
