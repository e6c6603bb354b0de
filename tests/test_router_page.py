"""The device front's table and plot (`springc.kws.evaluation.router_page`): every measured
figure reaches the table as measured, and the plot is written."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.router_page import front_plot, router_rows


def budget(db_work: float, db_sound: float, kt: float) -> dict:
    return {"stages": {"readouts": {"db_of_work": db_work, "db_of_sound": db_sound,
                                    "kt": kt}}, "readouts": 12, "bound_db": 52.9}


def test_the_front_reaches_its_table_and_plot(tmp_path: Path) -> None:
    routers = {"16 bins": {"accuracy": 0.3235, "ideal": 0.3235, "budget": budget(-17.2, -45.9,
                                                                               5988.0),
                           "noise": [{"device_mass": 1e-10, "accuracy": 0.3162},
                                     {"device_mass": 1e-8, "accuracy": 0.1912,
                                      "calibrated": 0.3235}],
                           "spread": [{"spread": 1e-3, "mean": 0.3254, "stderr": 0.0018}]}}
    squaring = {"8x3 S 1": {"accuracy": 0.61, "budget": budget(-370.0, -400.3, 2e-32),
                            "noise": [{"device_mass": 1e-40, "accuracy": 0.042}]}}
    rows = router_rows(routers)
    assert rows[2] == ("| 16 bins | 32.4 (32.4) | -17.2 | -45.9 | 499 | 31.6 at 1e-10 kg, "
                       "19.1 (32.4) at 1e-08 kg | 32.5 +- 0.2 at 0.001 |")
    assert front_plot(routers, squaring, tmp_path / "front.png").stat().st_size > 1000
