"""docs/api.md runs: its `python` blocks in order in one namespace (a folder where `netlists/`
is the repository's, so the page's paths work and what it writes stays out of the tree), and
its self-contained `python kws` block (a small synthesised corpus, a model, a classification)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "api.md"
BLOCK = re.compile(r"^```(python[^\n]*)\n(.*?)^```", re.M | re.S)


def blocks(tag: str) -> list[tuple[int, str]]:
    """(line, code) of every fenced block whose info string is exactly `tag`."""
    text = PAGE.read_text()
    return [(text[:m.start()].count("\n") + 1, m.group(2)) for m in BLOCK.finditer(text)
            if m.group(1).strip() == tag]


def run_blocks(tag: str, namespace: dict, folder: Path) -> None:
    """Execute the page's `tag` blocks in order in `folder`, each compiled under its line."""
    (folder / "netlists").symlink_to(ROOT / "netlists")
    here = os.getcwd()
    os.chdir(folder)
    try:
        for line, code in blocks(tag):
            exec(compile("\n" * line + code, f"{PAGE}:{line}", "exec"), namespace)
    finally:
        os.chdir(here)


def test_the_page_has_examples() -> None:
    assert len(blocks("python")) >= 6 and len(blocks("python kws")) == 1


def test_every_python_example_runs(tmp_path: Path) -> None:
    namespace: dict = {}
    run_blocks("python", namespace, tmp_path)
    assert (tmp_path / "sweep.png").stat().st_size > 0  # the sweep script's plot
    assert (tmp_path / "duffing.png").stat().st_size > 0
    assert abs(namespace["slope"] - 4) < 1e-3


@pytest.mark.skipif(not all(shutil.which(p) for p in ("espeak-ng", "flite", "festival")),
                    reason="text-to-speech engines not installed")
def test_the_keyword_spotting_example_runs(tmp_path: Path, monkeypatch) -> None:
    """The block synthesises its own corpus, trains and classifies: self-contained."""
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "cache"))
    namespace: dict = {}
    run_blocks("python kws", namespace, tmp_path)
    assert namespace["report"]["n"] > 0
    assert (tmp_path / "model").is_dir()


@pytest.mark.parametrize("name", ["load", "Netlist", "Result"])
def test_the_api_is_at_the_top_of_the_package(name: str) -> None:
    import springc

    assert getattr(springc, name) is getattr(__import__("springc.api").api, name)
