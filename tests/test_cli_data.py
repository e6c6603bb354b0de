"""`springc data synth` and `springc data info` through click's CliRunner and the installed
`springc` executable: output, exit status 1 with a named file for bad input, no traceback."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner
from springc_cli.main import main

sys.path.insert(0, str(Path(__file__).parent))
from kws_corpora import make_gscd

ENGINES_HERE = all(shutil.which(p) for p in ("espeak-ng", "flite", "festival"))


def _run(*args: str):
    return CliRunner().invoke(main, list(args))


def test_info_counts_per_split_and_label(tmp_path):
    root = make_gscd(tmp_path / "d")
    result = _run("data", "info", str(root), "--protocol", "lists",
                  "--plot", str(tmp_path / "counts.png"))
    assert result.exit_code == 0, result.output
    rows = {line.split()[0]: line.split()[1:] for line in result.output.splitlines() if line}
    assert rows["protocol:"] == ["lists"]
    assert rows["label"] == ["train", "validation", "test"]
    assert rows["yes"] == ["6", "2", "2"]
    assert rows["_unknown_"] == ["12", "4", "4"]
    assert rows["_silence_"] == ["2", "1", "1"]  # 10 % of 24, 8 and 8 word clips
    assert rows["total"] == ["26", "9", "9"]
    assert rows["majority"] == ["46.2%", "44.4%", "44.4%"]  # _unknown_: 12/26, 4/9
    assert "speakers: train 3, validation 1, test 1" in result.output
    assert (tmp_path / "counts.png").read_bytes()[:4] == b"\x89PNG"


def test_info_shows_the_balanced_held_out_splits_by_default(tmp_path):
    """yes and no have 2 clips per held-out split: _unknown_ (4 clips of cat and zero) is
    cut to 2 and 2 silence clips are cut; training is unchanged."""
    root = make_gscd(tmp_path / "d")
    result = _run("data", "info", str(root))
    assert result.exit_code == 0, result.output
    rows = {line.split()[0]: line.split()[1:] for line in result.output.splitlines() if line}
    assert rows["protocol:"] == ["balanced"]
    for label in ("yes", "no", "_unknown_", "_silence_"):
        assert rows[label][1:] == ["2", "2"], label
    assert rows["_unknown_"][0] == "12" and rows["_silence_"][0] == "2"
    assert rows["majority"][1:] == ["25.0%", "25.0%"]


def test_info_names_bad_files_and_continues(tmp_path):
    root = make_gscd(tmp_path / "d")
    bad = root / "yes" / "ffffffff_nohash_0.wav"
    bad.write_bytes(b"not audio")
    done = subprocess.run(["springc", "data", "info", str(root)], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert f"warning: {bad}: cannot read as audio" in done.stderr
    assert "problems: 1" in done.stdout


@pytest.mark.parametrize("setup, message", [
    (lambda root: None, "no such data folder"),
    (lambda root: root.mkdir(), "no word folders"),
    (lambda root: (root / "yes").mkdir(parents=True), "validation_list.txt: split list missing"),
])
def test_info_errors_exit_1_with_the_reason(tmp_path, setup, message):
    root = tmp_path / "d"
    setup(root)
    result = _run("data", "info", str(root))
    assert result.exit_code == 1
    assert message in result.output
    assert "Traceback" not in result.output


def test_synth_refuses_bad_requests(tmp_path):
    result = _run("data", "synth", str(tmp_path / "x"), "--words", "yes,banana")
    assert result.exit_code == 1 and "not GSCD words: banana" in result.output
    result = _run("data", "synth", str(tmp_path), "--clips", "5", "--words", "yes")
    assert result.exit_code == 1 and "already exists" in result.output
    result = _run("data", "synth", str(tmp_path / "y"), "--engines", "espeak,sam")
    assert result.exit_code == 1 and "unknown engine(s): sam" in result.output
    assert "Traceback" not in result.output


@pytest.mark.skipif(not ENGINES_HERE, reason="text-to-speech engines not installed")
def test_installed_springc_synthesises_and_reads_back(tmp_path):
    out = tmp_path / "corpus"
    done = subprocess.run(["springc", "data", "synth", str(out), "--clips", "12", "--seed", "2",
                           "--words", "yes,no", "--jobs", "2", "--engines", "flite,festival",
                           "--plot",
                           str(tmp_path / "ex.png")],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "12 clips (train" in done.stdout and f"corpus written to {out}" in done.stdout
    assert len(list((out / "yes").iterdir())) == 6
    assert (tmp_path / "ex.png").read_bytes()[:4] == b"\x89PNG"
    x, rate = sf.read(next((out / "no").iterdir()))
    assert rate == 16000 and x.shape == (16000,) and np.max(np.abs(x)) > 0.005
    info = subprocess.run(["springc", "data", "info", str(out)], capture_output=True, text=True,
                          timeout=120, check=False)
    assert info.returncode == 0, info.stderr
    assert "problems: 0" in info.stdout
