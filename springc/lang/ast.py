"""The abstract syntax tree of a .spr file: frozen dataclasses with source positions.

The parser builds it and nothing else; what the arguments mean is decided by elaboration.
Every node carries `loc`, a `SourceLoc` (file, line, column) of its first character.
"""

from __future__ import annotations

from dataclasses import dataclass

from springc.errors import SourceLoc

# --- expressions (inside `{...}`, interpolations and values) --------------------------------


@dataclass(frozen=True, slots=True)
class Num:
    """A number literal, already scaled by its SPICE suffix; `text` as written."""

    value: float
    text: str
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Var:
    """A parameter, loop variable, constant (`pi`, `e`) or `.data` array name."""

    name: str
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Unary:
    """`-x` or `+x`."""

    op: str
    operand: Expr
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Binary:
    """`a op b` for op in + - * / ** < <= > >= == !=; `loc` is the operator's."""

    op: str
    left: Expr
    right: Expr
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Call:
    """A function call `sqrt(x)`, `max(a, b)`."""

    func: str
    args: tuple[Expr, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Index:
    """An element of a `.data` array: `W[i]`, `W[i, j]`."""

    name: str
    indices: tuple[Expr, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Deviate:
    """Not written by users: the unit deviate of a random call in a Monte Carlo sample (z of
    `gauss`/`agauss`, w in (-1, 1) of `unif`/`aunif`; 0 outside a sample), the call being the
    `n`-th random call of the value of `key` at the site where this is evaluated. The tangent
    netlists of `springc.grad.derive` differentiate a draw with it."""

    func: str
    key: str
    n: int
    loc: SourceLoc


Expr = Num | Var | Unary | Binary | Call | Index | Deviate

# --- values and arguments ------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Word:
    """A name as written; `parts` alternates literal text and `{expr}` interpolations.
    A plain name has one str part (and `text` is that name)."""

    parts: tuple[str | Expr, ...]
    loc: SourceLoc

    @property
    def plain(self) -> bool:
        """True when the name has no interpolation."""
        return len(self.parts) == 1 and isinstance(self.parts[0], str)

    @property
    def text(self) -> str:
        """The name as written, with interpolations shown as `{...}`."""
        return "".join(p if isinstance(p, str) else "{...}" for p in self.parts)


@dataclass(frozen=True, slots=True)
class Brace:
    """A brace expression `{...}` used as a value."""

    expr: Expr
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Str:
    """A quoted string (file names); `text` without the quotes."""

    text: str
    loc: SourceLoc


Value = Num | Word | Brace | Str


@dataclass(frozen=True, slots=True)
class Keyword:
    """`key=value`."""

    key: str
    value: Value
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class CallArg:
    """`name(args)`: a force source (`sin(1 50)`) or a probe (`x(node)`)."""

    name: str
    args: tuple[Value, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Factor:
    """`node^exponent` in a monomial `P` element."""

    node: Word
    exponent: Value
    loc: SourceLoc


Arg = Num | Word | Brace | Str | Keyword | CallArg | Factor

# --- statements ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Element:
    """An element line: its name (first letter = kind) and its arguments in order."""

    name: Word
    args: tuple[Arg, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Directive:
    """A directive line other than the block directives; `name` lower-case without the dot."""

    name: str
    args: tuple[Arg, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Title:
    """`.title text`."""

    text: str
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Subckt:
    """`.subckt name ports... p=default ...` ... `.ends`."""

    name: str
    ports: tuple[Word, ...]
    params: tuple[Keyword, ...]
    body: tuple[Statement, ...]
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class For:
    """`.for var first last` ... `.endfor` (inclusive)."""

    var: str
    first: Value
    last: Value
    body: tuple[Statement, ...]
    loc: SourceLoc


Statement = Element | Directive | Title | Subckt | For


@dataclass(frozen=True, slots=True)
class Netlist:
    """A parsed file: its name (as given to the parser) and its top-level statements."""

    file: str
    statements: tuple[Statement, ...]
