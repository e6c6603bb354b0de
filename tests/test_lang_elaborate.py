"""AST to flat IR (springc/lang/elaborate.py): subcircuits, loops, includes, data, scoping,
probes and analyses, checked on the IR and, for the spec's example, against its physics."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from springc.lang import physics
from springc.errors import NetlistError
from springc.lang.ir import GROUND
from springc.lang import STDLIB_DIR, load_file, load_text

SPEC_EXAMPLE = Path(__file__).resolve().parents[1] / "netlists" / "examples" / "twomode_filter.spr"


def _load(text: str, **kw):
    net = load_text(text, "t.spr", **kw)
    net.validate()
    return net


def _error(text: str, filename: str = "t.spr", **kw) -> NetlistError:
    with pytest.raises(NetlistError) as info:
        load_text(text, filename, **kw)
    return info.value


def test_spec_example_has_the_two_modes_of_the_paper() -> None:
    # Two unit masses, springs wa^2, coupling (delta^2 - 1) wa^2 / 2: the symmetric mode rings
    # at wa and the antisymmetric one at wb = delta wa (paper Eq. filter-response).
    net = load_file(SPEC_EXAMPLE)
    wa, delta, alpha = 2 * math.pi * 1000, 1.1, 400.0
    omega = np.sqrt(np.linalg.eigvalsh(physics.stiffness_matrix(net)) / net.mass())
    assert omega == pytest.approx([wa, delta * wa], rel=1e-12)
    assert net.local_damping() == pytest.approx([alpha, alpha])
    assert net.forces.gain == pytest.approx(
        [alpha * (1 + delta**2) * wa**2, alpha * (1 - delta**2) * wa**2], rel=1e-14)
    assert [s.kind for s in net.forces.source] == ["in", "in"]
    assert net.tran.tstep == 1 / 64000 and net.tran.tstop == 1
    assert [p.label for p in net.probes] == ["x(xa)", "x(xb)"]


SUBCKT = """
.param k=5 g=7
X1 in out cell k={k*2}
X2 out q cell
.probe x(X1.mid) x(X2.a) v(X1.b) x(X2.Xl.p)
.subckt cell a b k=1 m={k/2}
.param kk={k + g}
M1 mid m={m}
K1 mid k={kk}
C1 a mid k={k}
Xl b leaf
.subckt leaf p
M p m=1
.ends leaf
.ends cell
Mi in m=1
"""


def test_subcircuits_flatten_with_paths_scopes_and_aliases() -> None:
    net = _load(SUBCKT)
    assert net.nodes == ["X1.mid", "in", "out", "X2.mid", "q"]
    assert net.masses.names == ["X1.M1", "X1.Xl.M", "X2.M1", "X2.Xl.M", "Mi"]
    # the override is evaluated in the caller's scope (k=10); the default m uses the
    # instance's k; the local .param sees the global g and the instance's k
    assert dict(zip(net.springs.names, net.springs.k)) == {"X1.K1": 17.0, "X2.K1": 8.0}
    assert list(net.masses.m) == [5.0, 1.0, 0.5, 1.0, 1.0]
    assert list(net.couplings.k) == [10.0, 1.0]
    assert [(i.path, i.subckt) for i in net.instances] == [
        ("X1", "cell"), ("X1.Xl", "leaf"), ("X2", "cell"), ("X2.Xl", "leaf")]
    assert net.element_loc("K", 0) .instance == "X1"
    assert net.element_loc("M", 1).instance == "X1.Xl" and net.element_loc("M", 4).instance == ""
    assert (net.element_loc("M", 1).line, net.element_loc("M", 1).col) == (13, 1)


def test_probes_resolve_ports_to_the_bound_node_and_keep_their_label() -> None:
    net = _load(SUBCKT)
    labels = {p.label: (p.quantity, net.nodes[p.node]) for p in net.probes}
    assert labels == {"x(X1.mid)": ("x", "X1.mid"), "x(X2.a)": ("x", "out"),
                      "v(X1.b)": ("v", "out"), "x(X2.Xl.p)": ("x", "q")}


def test_probe_inside_a_subcircuit_is_labelled_with_the_instance_path() -> None:
    net = _load(".subckt s a\nM1 a m=1\nM2 in m=1\n.probe v(in) x(a)\n.ends\nX7 n s\n")
    assert [(p.label, net.nodes[p.node]) for p in net.probes] == [
        ("v(X7.in)", "X7.in"), ("x(X7.a)", "n")]


def test_a_node_named_only_by_a_force_or_probe_is_still_a_node() -> None:
    # the IR can hold it; springc.check.checks reports that it carries no mass
    net = _load("M1 a m=1\nF1 b sin(1 2)\n.probe x(c) v(b)\n.ac c 1 2\n")
    assert net.nodes == ["a", "b", "c"]
    assert [(p.label, p.node) for p in net.probes] == [("x(c)", 2), ("v(b)", 1)]
    assert net.acs[0].node == 2


def test_ground_reaches_an_element_through_a_port() -> None:
    err = _error(SUBCKT.replace("X2 out q cell", "X2 out 0 cell"))
    assert err.message == "M: a mass cannot connect to ground (0)"
    assert err.loc.line == 13 and err.loc.instance == "X2.Xl"
    assert "(in instance X2.Xl)" in err.format()


def test_elements_may_name_nodes_inside_instances() -> None:
    net = _load(".subckt s p\nM1 p m=1\nM2 q m=1\n.ends\nX1 n s\nC1 X1.q X1.p K=3\n")
    assert net.nodes == ["n", "X1.q"]
    assert (net.couplings.i[0], net.couplings.j[0], net.couplings.k[0]) == (1, 0, 3.0)


def test_element_keys_are_case_insensitive_subcircuit_keys_are_not() -> None:
    net = _load("M1 a M=2 B=1 X0=0.5\n")
    assert (net.masses.m[0], net.masses.b[0], net.masses.x0[0]) == (2.0, 1.0, 0.5)
    err = _error(".subckt s p k=1\nM p m={k}\n.ends\nX1 n s K=2\n")
    assert err.message == "X1: subcircuit 's' has no parameter 'K'"
    assert err.diagnostic.hint == "did you mean 'k'?"


def test_dashpot_to_ground_either_way() -> None:
    net = _load("M1 a m=1\nB1 a 0 b=1\nB2 0 a b=2\n")
    assert list(net.dashpots.j) == [GROUND, GROUND] and list(net.dashpots.b) == [1.0, 2.0]


def test_nested_definitions_are_local() -> None:
    err = _error(".subckt outer a\n.subckt inner b\nM b m=1\n.ends\nXi a inner\n.ends\n"
                 "X1 n outer\nX2 m inner\n")
    assert err.message == "unknown subcircuit 'inner'" and err.loc.line == 8


def test_same_element_names_in_different_instances_are_fine() -> None:
    net = _load(".subckt s a\nM1 a m=1\n.ends\nX1 p s\nX2 q s\nM1 r m=1\n")
    assert net.masses.names == ["X1.M1", "X2.M1", "M1"]


def test_port_alias_used_before_the_instance_is_an_error() -> None:
    err = _error("M0 X1.a m=1\n.subckt s a\nM1 a m=1\n.ends\nX1 p s\n")
    assert "'X1.a' was used before X1 was instantiated" in err.message and err.loc.line == 5


def test_for_loops_nest_interpolate_and_scope_their_variable() -> None:
    net = _load(".param n=3\n.for i 1 {n}\nM{i} n{i} m={i}\n.for j {i+1} {n}\n"
                "C{i}_{j} n{i} n{j} k={10*i+j}\n.endfor\n.endfor\n.for i 5 4\nK n1 k=1\n"
                ".endfor\n")
    assert net.nodes == ["n1", "n2", "n3"] and list(net.masses.m) == [1.0, 2.0, 3.0]
    assert dict(zip(net.couplings.names, net.couplings.k)) == {
        "C1_2": 12.0, "C1_3": 13.0, "C2_3": 23.0}
    assert len(net.springs) == 0  # last < first: zero iterations, no error
    err = _error(".for i 1 2\nM{i} n{i} m=1\n.endfor\nK1 n1 k={i}\n")
    assert err.message == "undefined parameter 'i'" and err.loc.line == 4


def test_for_bounds_must_be_integers() -> None:
    err = _error(".for i {1/2} 3\n.endfor\n")
    assert err.message == "the first .for bound must be an integer, got 0.5"
    assert (err.loc.line, err.loc.col) == (1, 8)
    err = _error(".for i 1 nn\n.endfor\n")
    assert err.message == "undefined parameter 'nn'" and err.loc.col == 10


def test_interpolation_must_give_an_integer() -> None:
    err = _error(".for i 1 2\nM{i/2} n m=1\n.endfor\n")
    assert err.message == "an interpolation in a name must be an integer, got 0.5"
    assert (err.loc.line, err.loc.col) == (2, 4)


def test_parameters_apply_to_their_whole_scope() -> None:
    # as in SPICE, .param lines run before the elements of their scope, in their own order
    net = _load("K1 x k={a}\nX1 y s\n.param a=3\n.subckt s p\nM p m={2*c}\n.param c={a+1}\n"
                ".ends\nM1 x m=1\n")
    assert net.springs.k[0] == 3.0 and net.masses.m[0] == 8.0


def test_param_order_redefinition_and_constants() -> None:
    net = _load(".param a=2 b={a*3}\n.param a=10\nM1 x m={a+b}\n")
    assert net.masses.m[0] == 16.0
    err = _error(".param pi=3\n")
    assert "'pi' is a built-in constant" in err.message
    err = _error(".param b={a} a=1\n")
    assert err.message == "undefined parameter 'a'"


def test_include_relative_then_lib_dirs_then_stdlib_then_springc_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "lib").mkdir()
    (tmp_path / "env").mkdir()
    (tmp_path / "sub" / "local.spr").write_text(".subckt loc a\nM a m=1\n.ends\n")
    (tmp_path / "lib" / "mine.spr").write_text(".subckt mine a\nM a m=2\n.ends\n")
    (tmp_path / "env" / "envlib.spr").write_text(".subckt fromenv a\nM a m=3\n.ends\n")
    main = tmp_path / "main.spr"
    main.write_text('.include "sub/local.spr"\n.include "mine.spr"\n.include "envlib.spr"\n'
                    "X1 a loc\nX2 b mine\nX3 c fromenv\n")
    monkeypatch.setenv("SPRINGC_PATH", str(tmp_path / "env"))
    net = load_file(main, lib_dirs=[tmp_path / "lib"])
    assert list(net.masses.m) == [1.0, 2.0, 3.0]
    monkeypatch.delenv("SPRINGC_PATH")
    with pytest.raises(NetlistError) as info:
        load_file(main, lib_dirs=[tmp_path / "lib"])
    assert info.value.message == "cannot find include file 'envlib.spr'"
    assert str(STDLIB_DIR) in info.value.diagnostic.hint


def test_standard_library_is_found_from_anywhere(tmp_path: Path) -> None:
    assert STDLIB_DIR == Path(__file__).resolve().parents[1] / "netlists" / "lib"
    names = sorted(p.name for p in STDLIB_DIR.glob("*.spr"))
    assert names, "the standard library folder holds no .spr files"
    main = tmp_path / "use.spr"
    main.write_text(f'.include "{names[0]}"\nM1 a m=1\n')
    net = load_file(main)
    assert net.masses.names == ["M1"]


def test_include_cycle_names_the_chain(tmp_path: Path) -> None:
    (tmp_path / "a.spr").write_text('.include "b.spr"\n')
    (tmp_path / "b.spr").write_text('* b\n.include "a.spr"\n')
    with pytest.raises(NetlistError) as info:
        load_file(tmp_path / "a.spr")
    err = info.value
    assert err.message == "include cycle: a.spr -> b.spr -> a.spr"
    assert err.loc.line == 2 and Path(err.loc.file).name == "b.spr"


def test_a_file_never_includes_itself_it_means_the_library_block(tmp_path: Path) -> None:
    own = tmp_path / "readout.spr"  # the user's file has the library block's name
    own.write_text('.include "readout.spr"\nXr a readout tau=40\n')
    net = load_file(own)
    assert net.nodes == ["a"] and net.masses.names == ["Xr.Mr"]


def test_data_arrays_must_be_finite(tmp_path: Path) -> None:
    np.save(tmp_path / "w.npy", np.array([[1.0, 2.0], [np.inf, 4.0]]))
    (tmp_path / "m.spr").write_text('.data W "w.npy"\nM1 a m={W[0, 0]}\n')
    with pytest.raises(NetlistError) as info:
        load_file(tmp_path / "m.spr")
    assert "holds 1 non-finite value(s), the first inf at index [1, 0]" in info.value.message
    assert (info.value.loc.line, info.value.loc.col) == (1, 9)


def test_a_file_included_twice_in_one_scope_is_read_once(tmp_path: Path) -> None:
    (tmp_path / "d.spr").write_text(".subckt d a\nM a m=1\n.ends\n")
    (tmp_path / "e.spr").write_text('.include "d.spr"\n')
    main = tmp_path / "m.spr"
    main.write_text('.include "d.spr"\n.include "e.spr"\nX1 n d\n')
    assert load_file(main).masses.names == ["X1.M"]


def test_an_included_file_is_parsed_once_per_process_until_it_changes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two netlists that include the same block: the block is parsed once; rewritten, its new
    text is parsed (the new mass is what elaborates); the least recently used trees go."""
    from springc.lang import files, parser

    parsed = []
    real = parser.parse
    monkeypatch.setattr(parser, "parse", lambda text, name: parsed.append(name) or
                        real(text, name))
    block = tmp_path / "blk.spr"
    block.write_text(".subckt blk a\nM a m=2\n.ends\n")
    for k in range(2):
        (tmp_path / f"u{k}.spr").write_text(f'.include "blk.spr"\nX{k} n blk\n')
        assert load_file(tmp_path / f"u{k}.spr").masses.m[0] == 2.0
    blocks = lambda: [n for n in map(lambda p: Path(p).name, parsed) if n == "blk.spr"]  # noqa: E731
    assert blocks() == ["blk.spr"]  # the including netlists are parsed too, each its own
    block.write_text(".subckt blk a\nM a m=3\n.ends\n")
    assert load_file(tmp_path / "u1.spr").masses.m[0] == 3.0
    assert blocks() == ["blk.spr", "blk.spr"]
    monkeypatch.setattr(files, "PARSED_KEPT", 2)
    for k in range(3):
        files.parse_included(f"M{k} a m=1\n", f"kept{k}.spr")
    assert len(files._PARSED) == 2 and ("kept0.spr", "M0 a m=1\n") not in files._PARSED


def test_data_arrays_from_npy_and_csv(tmp_path: Path) -> None:
    np.save(tmp_path / "w.npy", np.array([[1.0, 2.0], [3.0, 4.0]]))
    (tmp_path / "v.csv").write_text("# header comment\n5\n6\n7\n")
    (tmp_path / "m.csv").write_text("1,2,3\n4,5,6\n")
    main = tmp_path / "d.spr"
    main.write_text('.data W "w.npy"\n.data V "v.csv"\n.data A "m.csv"\n'
                    "M1 a m={W[1, 0] + V[2] + A[1, 2]}\n")
    assert load_file(main).masses.m[0] == 3.0 + 7.0 + 6.0


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("bad.csv", "1,x\n", "cannot be read"),
        ("bad.npy", "not an npy file", "cannot be read"),
        ("w.txt", "1\n", "unsupported type '.txt'"),
        ("absent.npy", None, "not found"),
    ],
)
def test_bad_data_files_name_the_file(tmp_path: Path, name: str, content, message: str) -> None:
    if content is not None:
        (tmp_path / name).write_text(content)
    main = tmp_path / "d.spr"
    main.write_text(f'M1 a m=1\n.data W "{name}"\n')
    with pytest.raises(NetlistError) as info:
        load_file(main)
    assert message in info.value.message and name in info.value.message
    assert info.value.loc.line == 2


def test_sources_take_parameters_inside_subcircuits(tmp_path: Path) -> None:
    import soundfile as sf

    sf.write(tmp_path / "tone.wav", np.zeros(16), 8000)
    main = tmp_path / "s.spr"
    main.write_text('.subckt drv a ch=0 g=1\nM a m=1\nF a in({ch}) gain={g}\n'
                    'F2 a in(ch)\n.ends\nX1 n drv ch=2 g=3\nF3 n wav("tone.wav")\n')
    net = load_file(main)
    assert [(s.kind, s.channel) for s in net.forces.source] == [("in", 2), ("in", 2), ("wav", 0)]
    assert list(net.forces.gain) == [3.0, 1.0, 1.0]
    assert net.forces.source[2].path == str((tmp_path / "tone.wav").resolve())


def test_analyses_options_and_title() -> None:
    net = _load(".title  my net \nM1 a m=1\n.ac a 1 10k\n.ac a 2 3 points=7 input=1\n"
                ".options method=SSPRK3 substeps=2 precision=float32 outrate=16k\n")
    assert net.title == "my net"
    assert [(a.node, a.fstart, a.fstop, a.points, a.input) for a in net.acs] == [
        (0, 1.0, 1e4, 200, 0), (0, 2.0, 3.0, 7, 1)]
    assert net.options == {"method": "ssprk3", "substeps": 2, "precision": "float32",
                           "outrate": 16000.0}
    assert net.option_locs["outrate"].col == 53


@pytest.mark.parametrize(
    ("text", "message", "line"),
    [
        (".subckt s a\n.tran 1 2\n.ends\nX1 n s\n", ".tran is only allowed at the top level", 2),
        ("M1 a m=1\n.ac Xq.b 1 10\n", "unknown node 'Xq.b'", 2),
        ("M1 a m=1\n.ac a 10 1\n", ".ac needs 0 < fstart <= fstop", 2),
        ("M1 a m=1\n.ac a 1 10 pts=3\n", ".ac has no parameter 'pts'", 2),
        (".options method=rk4\n.options method=rk38\n", "option 'method' set twice", 2),
        (".options precision=float16\n", "precision must be float32 or float64", 1),
        (".options method=3\n", "option 'method' takes a word", 1),
        (".tran 0 1\n", ".tran step time must be > 0", 1),
        ("M1 a m=1\n.probe x(a) x(a)\n", "duplicate probe x(a)", 2),
        ("M1 a m=1\n.probe x(0)\n", "'0' is ground", 2),
        ("M1 a b m=1\n", "M1: a mass takes 1 node(s), got 2", 1),
        ("C1 a k=1\n", "C1: a coupling takes 2 node(s), got 1", 1),
        ("K1 a k=1 k=2\n", "K1: parameter 'k' given twice", 1),
        ("K1 a sin(1 2) k=1\n", "a spring (K) takes no source", 1),
        ("P1 c=1 a\n", "a monomial takes factors node^n", 1),
        ("P1 c=1\n", "a monomial needs at least one factor", 1),
        ("P1 c=1 a^1.5\n", "an exponent must be an integer, got 1.5", 1),
        ("M1 a m=1\nF1 a in(-1)\n", "input channel must be >= 0", 2),
        ("M1 a m=1\nF1 a sin(1 2) step(1 0)\n", "a force takes one source", 2),
        ('M1 a m="x"\n', 'expected a number, not the string "x"', 1),
        ("M1 a m=1\nX1 k=2\n", "an instance takes nodes, a subcircuit name", 2),
        ("M1 a m=1\n.title a\n.title b\n", ".title given twice", 3),
    ],
)
def test_semantic_errors(text: str, message: str, line: int) -> None:
    err = _error(text)
    assert message in err.message
    assert err.loc.line == line


def test_load_file_errors_are_user_errors(tmp_path: Path) -> None:
    with pytest.raises(NetlistError, match="no such netlist file"):
        load_file(tmp_path / "missing.spr")
    (tmp_path / "bin.spr").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(NetlistError, match="cannot read the netlist"):
        load_file(tmp_path / "bin.spr")


PIECES = ["M1", "K1", "X1", "C2", "Q1", "B1", "P1", "F1", "R1", ".param", ".subckt", ".ends",
          ".for", ".endfor", ".probe", ".tran", ".ac", ".options", ".data", ".include", ".title",
          "a", "b", "0", "n{i}", "X1.a", "{i}", "i", "1", "-1", "2.5k", "1k5", "m=1", "k=2",
          "a=0", "c=1", "gain=2", "=", "(", ")", ",", "^", "{", "}", "a^2", "sin(1 2)", "in(0)",
          "in", "pwl(0 0 1 1)", 'wav("x.wav")', "x(a)", "v(b)", "method=rk4", '"f.csv"',
          "{1/0}", "{a+}", "cell", "p=1", "+", "*", "; c", "\n", "\n", "\n+"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(PIECES), min_size=1, max_size=30))
def test_any_input_gives_a_netlist_or_a_user_error(pieces: list[str]) -> None:
    # never an internal error: bad input is a NetlistError with a location, good input a
    # structurally valid IR
    try:
        net = load_text(" ".join(pieces), "fuzz.spr")
    except NetlistError as err:
        assert err.loc is not None and err.format().startswith("fuzz.spr:")
    else:
        net.validate()
