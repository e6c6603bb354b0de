"""springc/check/store.py: a checked netlist kept on disk serves while the netlist, every
file it read and the options are unchanged, and never after."""

from __future__ import annotations

import numpy as np
import pytest

import springc
from springc.check import compiler, store
from springc.errors import CheckError
from springc.lang import parser

NET = '.include "blk.spr"\nX1 n blk\nK1 n k=4\n.probe x(n)\n.tran 10m 1\n'
BLOCK = ".subckt blk a\nM a m=2 b=0.1 x0=1\n.ends\n"


@pytest.fixture
def parses(monkeypatch, tmp_path) -> list[str]:
    """A private cache, and the names of the files the parser reads from now on."""
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "cache"))
    seen: list[str] = []
    real = parser.parse
    monkeypatch.setattr(parser, "parse", lambda text, name: seen.append(name) or
                        real(text, name))
    (tmp_path / "blk.spr").write_text(BLOCK)
    (tmp_path / "net.spr").write_text(NET)
    return seen


def test_an_unchanged_netlist_is_not_parsed_again(parses, tmp_path) -> None:
    first = springc.load(tmp_path / "net.spr")
    assert first.checked.entry is not None and len(parses) == 2  # the netlist, its include
    again = springc.load(tmp_path / "net.spr")
    assert len(parses) == 2 and again.checked.entry == first.checked.entry
    assert again.flat.masses.m.tolist() == [2.0]
    np.testing.assert_array_equal(again.checked.modes.eigenvalues,
                                  first.checked.modes.eigenvalues)
    assert again.simulate(tstop=0.1)["x(n)"][0, 0] == 1.0


def test_build_and_load_share_the_entry(parses, tmp_path) -> None:
    compiler.build(tmp_path / "net.spr")
    count = len(parses)
    report = springc.load(tmp_path / "net.spr").summary(as_dict=True)
    assert len(parses) == count and report["dofs"] == 1
    assert compiler.build(tmp_path / "net.spr").summary() == \
        springc.load(tmp_path / "net.spr").summary()


def test_an_edited_include_is_read_again(parses, tmp_path) -> None:
    springc.load(tmp_path / "net.spr")
    (tmp_path / "blk.spr").write_text(BLOCK.replace("m=2", "m=3"))
    assert springc.load(tmp_path / "net.spr").flat.masses.m.tolist() == [3.0]


def test_a_new_file_that_shadows_a_library_block_is_seen(parses, tmp_path,
                                                         monkeypatch) -> None:
    """An include found in the standard library is looked for beside the netlist first: a
    file created there later must win, as it would without the cache."""
    (tmp_path / "blk.spr").unlink()
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "blk.spr").write_text(BLOCK)
    monkeypatch.setenv("SPRINGC_PATH", str(lib))
    assert springc.load(tmp_path / "net.spr").flat.masses.m.tolist() == [2.0]
    (tmp_path / "blk.spr").write_text(BLOCK.replace("m=2", "m=5"))
    assert springc.load(tmp_path / "net.spr").flat.masses.m.tolist() == [5.0]


def test_a_model_file_is_checked_once_and_shares_loads_entry(parses, tmp_path) -> None:
    """`store.checked_file` (a keyword-spotting model's classifier.spr in `eval` and
    `classify`) keeps the entry `springc.load` keeps; a file with `.step` is checked at its
    nominal design each time."""
    first = store.checked_file(tmp_path / "net.spr")
    assert first.entry is not None and len(parses) == 2
    again = store.checked_file(tmp_path / "net.spr")
    assert len(parses) == 2 and again.entry == first.entry
    assert springc.load(tmp_path / "net.spr").checked.entry == first.entry and len(parses) == 2
    (tmp_path / "swept.spr").write_text(NET + ".step param k 1 2 1\n.param k=3\n")
    for _ in range(2):
        assert store.checked_file(tmp_path / "swept.spr").net.n == 1
    assert parses.count(str(tmp_path / "swept.spr")) == 2


def test_options_text_and_points_make_their_own_entries(parses, tmp_path) -> None:
    plain = springc.load(tmp_path / "net.spr")
    pinned = springc.load(tmp_path / "net.spr", method="rk4")
    assert pinned.checked.entry != plain.checked.entry and pinned.checked.pinned
    swept = tmp_path / "swept.spr"
    swept.write_text(NET.replace("k=4", "k={kk}") + ".param kk=4\n.step kk list 4 9\n")
    assert springc.load(swept).checked.entry is None  # points: elaborated when simulated
    edited = tmp_path / "net.spr"
    edited.write_text(NET.replace("k=4", "k=5"))
    assert springc.load(edited).checked.entry != plain.checked.entry


def test_a_damaged_entry_is_a_miss(parses, tmp_path) -> None:
    entry = springc.load(tmp_path / "net.spr").checked.entry
    path = store.folder() / f"{entry}.pkl"
    path.write_bytes(path.read_bytes()[:40])
    count = len(parses)
    again = springc.load(tmp_path / "net.spr")
    # parsed and checked again (the include's tree is the process's own, kept in memory)
    assert parses[count:] == [str(tmp_path / "net.spr")]
    assert again.flat.masses.m.tolist() == [2.0] and again.checked.entry == entry


def test_a_refused_netlist_leaves_no_entry(parses, tmp_path) -> None:
    bad = tmp_path / "bad.spr"
    bad.write_text("M1 a m=1\nK1 a k=-1\n.tran 1m 1\n")
    with pytest.raises(CheckError):
        springc.load(bad)
    assert not store.folder().exists()


def test_a_memo_is_computed_once_per_key_and_again_when_damaged(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path))
    calls = []

    def compute(value):
        calls.append(value)
        return {"value": value, "array": np.arange(3.0) * value}

    first = store.memo("a choice", ["network", b"\x00sample"], lambda: compute(1))
    again = store.memo("a choice", ["network", b"\x00sample"], lambda: compute(2))
    assert calls == [1] and again["value"] == 1 and np.array_equal(again["array"], first["array"])
    store.memo("a choice", ["network", b"\x00other sample"], lambda: compute(3))
    store.memo("another choice", ["network", b"\x00sample"], lambda: compute(4))
    # the parts are delimited: moving a byte from one part to the next is another key
    store.memo("a choice", ["networ", b"k\x00sample"], lambda: compute(5))
    assert calls == [1, 3, 4, 5]
    for entry in (tmp_path / "checked" / "memo").glob("*.pkl"):
        entry.write_bytes(b"damaged")
    assert store.memo("a choice", ["network", b"\x00sample"], lambda: compute(6))["value"] == 6
