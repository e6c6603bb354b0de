"""docs/results-stiffness.md's writer: every measured figure reaches its table as measured,
the page's own reading survives a regeneration, and the plot is written beside the page."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.device_page import READING
from springc.kws.evaluation.stiffness_page import write_page


def row(factor: float, acc: float, db: float) -> dict:
    """A stored row whose stages lie 10 dB apart, from `db` at the low-pass masses down."""
    # k_B T from dB of the sound: the sound is 2.4e8 k_B T, 84 dB
    stages = {name: {"db_of_sound": db - 10 * k, "kt": 10 ** ((db - 10 * k + 84) / 10)}
              for k, name in enumerate(("low-pass masses", "compressors", "terminals",
                                        "mvm heads", "readouts"))}
    return {"size": "4x2", "factor": factor, "epsilon": 1e-5, "threshold": 1e-3,
            "squarer_range": 10.0, "accuracy": acc, "n": 120,
            "budget": {"stages": stages, "bound_db": 52.9}}


def test_stage_stiffness_reaches_its_table_and_plot(tmp_path: Path) -> None:
    """Each size and factor's accuracy and the later stages' dB of the sound as measured,
    the readouts' k_B T, and the plot beside the page."""
    st = {"b": row(100.0, 0.5, -140.5), "a": row(1.0, 0.475, -160.5)}
    text = write_page(st, tmp_path / "page.md", intro="").read_text()
    assert ("| 4x2 | 100 | 10 | 1e-05 | 0.001 | 50.0 (120) | -140.5 | -150.5 | -160.5 "
            "| -170.5 | -180.5 | 2.2e-10 |") in text
    assert "| 4x2 | 1 | 10 | 1e-05 | 0.001 | 47.5 (120) | -160.5 |" in text
    # by size, range, eps, threshold, then stiffness, whatever the order measured
    assert text.index("| 4x2 | 1 | 10 |") < text.index("| 4x2 | 100 | 10 |")
    assert "| design | study |" not in text  # no noise or population measured
    st["b"]["noise"] = [{"device_mass": 1e-36, "accuracy": 0.25, "noiseless": 0.5,
                         "decision_error": 0.379}]
    st["b"]["spread"] = [{"spread": 1e-3, "mean": 0.495, "stderr": 0.005, "nominal": 0.5}]
    text = write_page(st, tmp_path / "page.md", intro="").read_text()
    assert "| 4x2, S 100, R 10, eps 1e-05 | noise at 1e-36 kg | 25.0 | 50.0 | 0.379 |" in text
    assert "| 4x2, S 100, R 10, eps 1e-05 | spread 0.001, mean device | 49.5 +- 0.5 | 50.0 |" \
        in text
    assert (tmp_path / "page.png").stat().st_size > 0


def test_reading_survives_regeneration(tmp_path: Path) -> None:
    md = tmp_path / "page.md"
    st = {"a": row(1.0, 0.475, -160.5)}
    write_page(st, md, intro=f"{READING}\n\nStiffer stages take more.\n")
    write_page(st, md)
    text = md.read_text()
    assert text.count(READING) == 1 and "Stiffer stages take more." in text


def test_speaker_folds_follow_the_first_table(tmp_path: Path) -> None:
    cv = {"fold0 summing": {"accuracy": 0.50, "n": 100},
          "fold0 summing-stiff": {"accuracy": 0.52, "n": 100,
                                  "spread": {"mean": 0.51, "nominal": 0.52}}}
    text = write_page({"a": row(1.0, 0.475, -160.5)}, tmp_path / "page.md", intro="",
                      cv=cv).read_text()
    assert text.index("## Against the stage stiffness") < text.index("## Cross-validated")
    assert "| summing-stiff | 52.0 (100) | 52.0 +- 0.0 | +2.0 +- 0.0 | 51.0 (52.0) |" in text
