"""`springc figures OUTDIR` (springc/design/figures.py, cli/figures.py): the building-block figures
are written as PNGs with the measured numbers beside them. The experiments behind them are
asserted on in the other tests/test_lib_*.py files; here only the command itself."""

from __future__ import annotations

import json

from click.testing import CliRunner
from springc_cli.main import main


def test_figures_without_simulation(tmp_path):
    """melbank (Fig. 4), dispersion (Fig. 3d) and mvm need no simulator: quick to make."""
    res = CliRunner().invoke(main, ["figures", str(tmp_path / "out"), "--only", "melbank",
                                    "--only", "dispersion", "--only", "mvm"])
    assert res.exit_code == 0, res.output
    out = tmp_path / "out"
    for name in ("melbank", "dispersion", "mvm"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    numbers = json.loads((out / "figures.json").read_text())
    assert numbers["dispersion"]["max_rel_error_modes"] < 1e-9
    assert numbers["mvm"]["max_principal_angle"] < 1e-8
    assert numbers["mvm"]["max_rel_error_in_band"] < 0.01
    assert numbers["melbank"]["misfit_two_mode_mean"] < numbers["melbank"][
        "misfit_single_mode_mean"]
    assert sorted(p.name for p in out.iterdir()) == ["dispersion.png", "figures.json",
                                                    "melbank.png", "mvm.png"]


def test_outdir_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("")
    res = CliRunner().invoke(main, ["figures", str(tmp_path / "f"), "--only", "melbank"])
    assert res.exit_code == 1 and "is a file" in res.output
    assert "Traceback" not in res.output
