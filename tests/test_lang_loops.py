"""Regular `.for` loops expanded as arrays (springc/lang/loops.py) must elaborate to exactly the
flat netlist of the general path, one iteration at a time: names, node order, values to the
bit, source locations, and the same error where there is one."""

from __future__ import annotations

from unittest import mock

import numpy as np
import pytest

from springc.errors import NetlistError
from springc.lang import load_text, loops
from springc.lang.elaborate import _Elaborator

HEAD = ".param n=5 k0=2.5 w={2*pi*3}\n"
# each regular (expanded as arrays) unless marked otherwise in IRREGULAR
REGULAR = {
    "chain": """
.for i 0 {n-1}
M{i} n{i} m=1 b={0.1*i} x0={i/3} v0=-1
K{i} n{i} k={k0*(i+1)}
.endfor
.for i 0 {n-2}
C{i} n{i} n{i+1} k={w**2/7} a={1 + (i > 2)}
.endfor
""",
    "lattice": """
.for i 0 {n-1}
.for j 0 {n-2}
M{i}_{j} s{i}_{j} m={1+i*j}
Ma{i}_{j} s{i}_{j} m=0.5
Cx{i}_{j} s{i}_{j} s{i}_{j+1} k={sqrt(i+j+1)}
Cy{i}_{j} s{j}_{i} s{i}_{j} k={i**2 + j**0.5} a={max(i, j, 1)}
.endfor
.endfor
""",
    "mixed kinds": """
M0 a m=1
.for i 1 {n}
B{i} n{i} 0 b={i}
Bg{i} 0 n{i} b={exp(-i)}
D{i} n{i} l={log(i) + sin(i)/cos(i)}
Q{i} n{i} a g={1/i} a={-(-2)}
M{i} n{i} m={i == 3 + 0.5*(i != 2) + floor(i/2) - ceil(i/3) + abs(1-i)}
.endfor
K1 a k=1
""",
    "data": """
.data W "w.csv"
.for i 0 2
M{i} p{i} m={W[i, 1]}
K{i} p{i} k={W[2-i, 0] * i}
.endfor
""",
    "subcircuit": """
.subckt cell left right kc=1
.for s 0 3
M{s} r{s} m=1
C{s} left r{s} k={kc*s + 1}
C{s}b r{s} right k=2
.endfor
.ends cell
Xc0 a0 a1 cell
Xc1 a1 a2 cell kc=1
Xc2 a2 a3 cell kc={n}
M9 a0 m=1
M10 a3 m=1
C9 Xc1.r2 a0 k=1
""",
    "loop variable names": """
.for i 0 3
.for j 2 3
K{i}{j} x{i*10+j} k=i
M{i}{j} x{i*10+j} m=j
.endfor
.endfor
""",
    "shadowing and random nominal": """
.param i=100
.for j 0 2
M{j} q{j} m={i + j + gauss(1, 0.1)}
.endfor
""",
    "empty and single": """
.for i 3 1
M{i} z{i} m=1
.endfor
.for i 7 7
M{i} z{i} m=1
.endfor
.for i 0 2
.for j 2 1
M{i}_{j} y m=1
.endfor
.endfor
""",
}
IRREGULAR = {
    "force in the body": """
.for i 0 2
M{i} n{i} m=1
F{i} n{i} sin(1 {i+1})
.endfor
""",
    "param in the body": """
.for i 0 2
.param h={i/2}
M{i} n{i} m={1+h}
.endfor
""",
    "dependent inner bounds": """
.for i 0 3
.for j {i} 3
C{i}_{j} n{i} n{j}x k=1
.endfor
.endfor
M0 n0 m=1
""",
    "duplicate name": """
.for i 0 2
M1 n{i} m=1
.endfor
""",
    "duplicate of an earlier element": """
M2 a m=1
.for i 0 2
M{i} n{i} m=1
.endfor
""",
    "division by zero": """
.for i 0 3
M{i} n{i} m={1/(i-2)}
.endfor
""",
    "overflow": """
.for i 0 3
M{i} n{i} m={1e200 * 10**(100*i)}
.endfor
""",
    "sqrt of a negative": """
.for i 0 3
M{i} n{i} m={sqrt(1-i)}
.endfor
""",
    "negative name": """
.for i 0 3
M{i} n{i-2} m=1
.endfor
""",
    "fractional name": """
.for i 0 3
M{i} n{i/2} m=1
.endfor
""",
    "ground": """
.for i 0 3
C{i} n{i} 0 k=1
.endfor
""",
    "dashpot between grounds": """
.for i 0 1
B{i} 0 0 b=1
.endfor
""",
    "undefined parameter": """
.for i 0 3
M{i} n{i} m={q*i}
.endfor
""",
    "missing parameter": """
.for i 0 3
C{i} n{i} n{i+1} a=1
.endfor
""",
    "index out of range": """
.data W "w.csv"
.for i 0 3
M{i} n{i} m={W[i, 0]}
.endfor
""",
    "array as a number": """
.data W "w.csv"
.for i 0 3
M{i} n{i} m=W
.endfor
""",
    "port bound to ground": """
.subckt s p
.for i 0 1
C{i} p r{i} k=1
M{i} r{i} m=1
.endfor
.ends s
X1 0 s
""",
}


def _fingerprint(net) -> list:
    """Everything of a flat netlist that the elaborator sets, to compare two of them."""
    out = [net.text(), [str(loc) for loc in net.node_locs], [p.loc for p in net.probes]]
    for letter, table in net.tables().items():
        out.append((letter, [str(loc) for loc in table.locs]))
        for key, column in vars(table).items():
            if isinstance(column, np.ndarray):
                out.append((letter, key, column.dtype.str, column.tobytes()))
    return out


def _elaborate(text: str, tmp_path, general: bool) -> list | str:
    (tmp_path / "w.csv").write_text("0.5,1.5\n2,3\n4,5.25\n")
    netlist = tmp_path / "net.spr"
    netlist.write_text(HEAD + text + "M_last n0 m=1\n")
    try:
        if general:
            with mock.patch.object(loops, "expand", return_value=None):
                return _fingerprint(load_text(netlist.read_text(), str(netlist)))
        return _fingerprint(load_text(netlist.read_text(), str(netlist)))
    except NetlistError as err:
        return f"{err.loc}: {err.message} ({err.diagnostic.hint})"


@pytest.mark.parametrize("name", [*REGULAR, *IRREGULAR])
def test_arrays_and_the_general_path_agree(name: str, tmp_path) -> None:
    text = {**REGULAR, **IRREGULAR}[name]
    assert _elaborate(text, tmp_path, general=False) == _elaborate(text, tmp_path, general=True)


def _paths(text: str, tmp_path) -> list[bool]:
    """Per loop elaborated, True where it was expanded as arrays."""
    taken = []
    expand_rows = _Elaborator._loop_rows

    def spy(self, stmt, scope):
        taken.append(expand_rows(self, stmt, scope))
        return taken[-1]

    with mock.patch.object(_Elaborator, "_loop_rows", spy):
        result = _elaborate(text, tmp_path, general=False)
    assert taken, result
    return taken


@pytest.mark.parametrize("name", list(REGULAR))
def test_regular_loops_are_expanded_as_arrays(name: str, tmp_path) -> None:
    assert all(_paths(REGULAR[name], tmp_path))
    assert not isinstance(_elaborate(REGULAR[name], tmp_path, general=False), str)


@pytest.mark.parametrize("name", ["force in the body", "param in the body", "duplicate name",
                                  "division by zero", "negative name", "ground"])
def test_irregular_loops_are_left_to_the_general_path(name: str, tmp_path) -> None:
    assert not _paths(IRREGULAR[name], tmp_path)[0]


def test_errors_of_irregular_loops_name_the_iteration(tmp_path) -> None:
    message = _elaborate(IRREGULAR["division by zero"], tmp_path, general=False)
    assert message.startswith(f"{tmp_path / 'net.spr'}:4:") and "division by zero" in message
    message = _elaborate(IRREGULAR["duplicate name"], tmp_path, general=False)
    assert "duplicate element name 'M1'" in message


def test_a_long_general_loop_shows_its_progress(tmp_path, capsys) -> None:
    text = IRREGULAR["force in the body"].replace("0 2", "0 400")
    with mock.patch("springc.lang.elaborate.SHOW_PROGRESS_AFTER", 0.0):
        assert not isinstance(_elaborate(text, tmp_path, general=False), str)
    err = capsys.readouterr().err
    assert f"elaborating .for i ({tmp_path / 'net.spr'}:3" in err and "/401" in err
    _elaborate(text, tmp_path, general=False)  # under the default 3 s: nothing shown
    assert capsys.readouterr().err == ""
