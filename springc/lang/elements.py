"""What each element letter takes, and the force sources: the per-letter rules of the
language table, checked with positions before anything reaches the IR builder."""

from __future__ import annotations

from dataclasses import dataclass

from springc.errors import NetlistError, SourceLoc
from springc.lang.ir import Source
from springc.lang import ast
from springc.lang.expr import Env, closest, int_value, keyed, value
from springc.lang.files import beside


@dataclass(frozen=True)
class Spec:
    """An element letter: what it is called, its nodes, required and optional parameters."""

    what: str
    nodes: int
    required: tuple[str, ...]
    optional: dict[str, float]


SPECS = {
    "M": Spec("mass", 1, ("m",), {"b": 0.0, "x0": 0.0, "v0": 0.0}),
    "K": Spec("spring", 1, ("k",), {}),
    "D": Spec("Duffing spring", 1, ("l",), {}),
    "C": Spec("coupling", 2, ("k",), {"a": 1.0}),
    "Q": Spec("quadratic coupling", 2, ("g",), {"a": 1.0}),
    "B": Spec("dashpot", 2, ("b",), {}),
    "P": Spec("monomial", 0, ("c",), {}),
    "F": Spec("force", 1, (), {"gain": 1.0}),
}
LETTERS = "MKDCQBPFX"
LETTERS_HINT = ("elements are M K D C Q B P F X (mass, spring, Duffing, coupling, quadratic "
                "coupling, dashpot, monomial, force, instance)")

# source -> (fewest, most) arguments (None: no limit), and how it is written
SOURCES = {
    "in": (0, 1, "in(k): channel k of the simulator's input signals (default 0)"),
    "sin": (2, 3, "sin(amp freq [phase]): amp sin(2 pi freq t + phase)"),
    "gauss": (3, 3, "gauss(amp t0 sigma): amp exp(-(t - t0)^2 / (2 sigma^2))"),
    "step": (2, 2, "step(amp t0)"),
    "pwl": (2, None, "pwl(t1 v1 t2 v2 ...): pairs with increasing times"),
    "wav": (1, 2, 'wav("file.wav" [channel]): a sound file, path relative to the netlist'),
}
FORCE_HINT = ("e.g. F1 a in(0) gain=2, or sin(amp freq), gauss(amp t0 sigma), step(amp t0), "
              'pwl(t1 v1 t2 v2 ...), wav("file.wav")')


def split_args(args) -> tuple[list, list, list, list]:
    """Arguments by kind: plain values, key=value pairs, calls, factors."""
    plain, keywords, calls, factors = [], [], [], []
    for arg in args:
        match arg:
            case ast.Keyword():
                keywords.append(arg)
            case ast.CallArg():
                calls.append(arg)
            case ast.Factor():
                factors.append(arg)
            case ast.Num() | ast.Word() | ast.Brace() | ast.Str():
                plain.append(arg)
            case _:
                raise TypeError(f"unknown argument {arg!r}")
    return plain, keywords, calls, factors


def check_kinds(name: str, letter: str, calls: list, factors: list) -> None:
    """Only a force takes a source call and only a monomial takes factors."""
    spec = SPECS[letter]
    if calls and letter != "F":
        raise NetlistError(f"a {spec.what} ({letter}) takes no source or call "
                           f"'{calls[0].name}(...)'", calls[0].loc)
    if factors and letter != "P":
        raise NetlistError(f"a {spec.what} ({letter}) takes no factor 'node^n'", factors[0].loc)


def params(name: str, spec: Spec, keywords: list, env: Env, loc: SourceLoc) -> dict:
    """The element's parameter values: defaults, then its `key=value` arguments (keys are
    case-insensitive, as in SPICE); unknown, repeated or missing keys are errors. A random
    call in a value draws at (`env`'s site, key) in a Monte Carlo sample."""
    values = dict(spec.optional)
    given: set[str] = set()
    for kw in keywords:
        key = kw.key.lower()
        if key not in values and key not in spec.required:
            known = spec.required + tuple(spec.optional)
            guess = closest(key, known)
            hint = f"did you mean '{guess}'?" if guess else f"it takes {', '.join(known)}"
            raise NetlistError(f"{name}: a {spec.what} has no parameter '{kw.key}'", kw.loc,
                               hint)
        if key in given:
            raise NetlistError(f"{name}: parameter '{key}' given twice", kw.loc)
        given.add(key)
        values[key] = value(kw.value, keyed(env, key))
    for key in spec.required:
        if key not in given:
            raise NetlistError(f"{name}: missing parameter '{key}' of the {spec.what}", loc,
                               f"write {key}=<value>")
    return values


def node_count(name: str, spec: Spec, plain: list, count: int, loc: SourceLoc) -> None:
    """An error unless exactly `count` nodes were given."""
    if len(plain) != count:
        where = plain[count].loc if len(plain) > count else loc
        raise NetlistError(f"{name}: a {spec.what} takes {count} node(s), got {len(plain)}",
                           where)


def force_source(name: str, plain: list, calls: list, env: Env, loc: SourceLoc) -> Source:
    """The signal of an `F` element: a call like `sin(1 50)`, or the bare word `in`."""
    if not calls:
        word = plain[1] if len(plain) == 2 else None
        if isinstance(word, ast.Word) and word.plain and word.parts[0].lower() == "in":
            return Source("in", (), 0)
        raise NetlistError(f"{name}: a force needs a node and a source", loc, FORCE_HINT)
    if len(calls) > 1:
        raise NetlistError(f"{name}: a force takes one source", calls[1].loc)
    return source(calls[0], env)


def source(call: ast.CallArg, env: Env) -> Source:
    """A `Source` from a call, its arguments checked; `sin` gets its phase (default 0)."""
    kind = call.name.lower()
    if kind not in SOURCES:
        guess = closest(kind, SOURCES)
        hint = f"did you mean '{guess}'?" if guess else f"known: {', '.join(SOURCES)}"
        raise NetlistError(f"unknown source '{call.name}'", call.loc, hint)
    low, high, usage = SOURCES[kind]
    n = len(call.args)
    if n < low or (high is not None and n > high):
        want = (f"{low}" if low == high else
                f"{low} or more" if high is None else f"{low} to {high}")
        raise NetlistError(f"{kind}() takes {want} arguments, got {n}", call.loc, usage)
    if kind == "wav":
        return _wav(call, env)
    if kind == "in":
        channel = int_value(call.args[0], env, "an input channel") if call.args else 0
        if channel < 0:
            raise NetlistError(f"input channel must be >= 0, got {channel}", call.args[0].loc)
        return Source("in", (), channel)
    args = tuple(float(value(a, env)) for a in call.args)
    if kind == "sin" and n == 2:
        args += (0.0,)
    if kind == "pwl":
        _check_pwl(call, args)
    return Source(kind, args)


def _check_pwl(call: ast.CallArg, args: tuple[float, ...]) -> None:
    if len(args) % 2:
        raise NetlistError(f"pwl() takes pairs (time value), got {len(args)} numbers",
                           call.loc, SOURCES["pwl"][2])
    times = args[0::2]
    for k in range(1, len(times)):
        if not times[k] > times[k - 1]:
            raise NetlistError(f"pwl() times must increase: {times[k]:g} follows "
                               f"{times[k - 1]:g}", call.args[2 * k].loc)


def _wav(call: ast.CallArg, env: Env) -> Source:
    name = call.args[0]
    if not isinstance(name, ast.Str):
        raise NetlistError("wav() takes a quoted file name", name.loc, 'write wav("file.wav")')
    path = beside(name)
    if not path.is_file():
        raise NetlistError(f"wav file '{name.text}' not found (looked for {path})", name.loc)
    channel = int_value(call.args[1], env, "a channel") if len(call.args) > 1 else 0
    if channel < 0:
        raise NetlistError(f"channel must be >= 0, got {channel}", call.args[1].loc)
    return Source("wav", (), channel, str(path.resolve()))
