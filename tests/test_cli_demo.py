"""`springc demo` end to end on a tiny generated corpus (chirps and tones as words): every
stage runs, the table and the plots are written; a bad corpus is a user error."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from kws_corpora import make_corpus

from springc_cli.main import main
from shared_cache import KERNELS


@pytest.fixture(autouse=True)
def _kernel_cache(monkeypatch):
    monkeypatch.setenv("SPRINGC_CACHE", str(KERNELS))


def test_demo_trains_every_realisation_and_simulates_the_networks(tmp_path):
    data = make_corpus(tmp_path / "data", per_speaker=2)
    out = tmp_path / "demo"
    res = CliRunner().invoke(main, ["demo", "--out", str(out), "--data", str(data), "--bins",
                                    "2", "--delays", "2", "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "mass-spring network (simulated end to end)" in res.output
    assert "device network, summing heads (end to end)" in res.output
    assert "router, linear passive, 16 bins (end to end)" in res.output
    assert "time per stage:" in res.output
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["accuracy"]) == 5
    assert all(0.0 <= a <= 1.0 for a in summary["accuracy"].values())
    for name in ("accuracy.png", "features.png", "confusion-network.png",
                 "model-mass-spring/classifier.spr", "model-mass-spring/head0.spr",
                 "model-mass-spring/features.spr", "model-digital/weights.npz",
                 "model-device/classifier.spr", "model-router/router.spr"):
        assert (out / name).is_file(), name


def test_demo_on_a_missing_corpus_is_a_user_error(tmp_path):
    res = CliRunner().invoke(main, ["demo", "--out", str(tmp_path / "o"), "--data",
                                    str(tmp_path / "nothing"), "--jobs", "1"])
    assert res.exit_code == 1
    assert "nothing" in res.output and "Traceback" not in res.output
