"""springc.bench.grad: the gradient-cost table measures what it says."""

from __future__ import annotations

from springc.bench import grad as gradbench


def test_quick_measurement_and_table():
    rows = gradbench.measure(quick=True)
    (row,) = rows
    assert row["forward_s"] > 0 and row["gradient_s"] > 0
    assert row["ratio"] == row["gradient_s"] / row["forward_s"]
    table = gradbench.markdown(rows)
    assert f"| {row['dofs']} | {row['runs']} | {row['steps']} | 6 |" in table


def test_report_runs_only_with_the_whole_suite():
    said = []
    gradbench.report(["feature"], True, said.append)
    assert said == []
    gradbench.report(None, True, said.append)
    assert len(said) == 1 and "gradient" in said[0]
