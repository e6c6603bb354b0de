"""The random functions of a value: `gauss`, `agauss`, `unif`, `aunif` (docs/language.md,
"Sweeps and Monte Carlo").

Without a Monte Carlo sample each is its nominal value. In sample `i` of seed `s` the draw at
site (`path`, `key`, `n`), the `n`-th random call of the value that parameter or element key
`key` of instance or element `path` is given, is a function of those five alone: splitmix64
hashes them into 64 random bits per stream, a uniform is the top 53 bits, a normal is
Box-Muller of two streams, all in float64 numpy. Any order of evaluation, any subset of
samples and any number of threads draws the same numbers; the scalar draw of the elaborator
is the vectorised one at one sample, so the two agree bitwise.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from springc.errors import NetlistError, SourceLoc

# name -> (fewest, most arguments, how it is written)
FUNCTIONS = {
    "gauss": (2, 3, "gauss(nom, rvar[, sigma]): normal, deviation |nom| rvar / sigma"),
    "agauss": (2, 3, "agauss(nom, avar[, sigma]): normal, deviation avar / sigma"),
    "unif": (2, 2, "unif(nom, rvar): uniform on nom (1 +- rvar)"),
    "aunif": (2, 2, "aunif(nom, avar): uniform on nom +- avar"),
}
MAX_SEED = 2**63  # seeds are integers 0 <= seed < MAX_SEED, as `.options seed=`

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)


def check_args(func: str, args: list[float], loc: SourceLoc) -> None:
    """A located error unless `args` suit `func`: the count, a spread >= 0, a sigma > 0."""
    low, high, usage = FUNCTIONS[func]
    if not low <= len(args) <= high:
        want = f"{low}" if low == high else f"{low} or {high}"
        raise NetlistError(f"{func}() takes {want} arguments, got {len(args)}", loc, usage)
    what = "rvar" if func in ("gauss", "unif") else "avar"
    if not args[1] >= 0:
        raise NetlistError(f"{func}(): {what} must be >= 0, got {args[1]:g}", loc, usage)
    if len(args) == 3 and not args[2] > 0:
        raise NetlistError(f"{func}(): sigma must be > 0, got {args[2]:g}", loc, usage)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64's output function of `x` + the golden ratio (uint64 arrays wrap)."""
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _MUL1
    z = (z ^ (z >> np.uint64(27))) * _MUL2
    return z ^ (z >> np.uint64(31))


def _site_bits(path: str, key: str, n: int) -> np.uint64:
    """64 bits naming a site, the same in every process (unlike Python's `hash`)."""
    digest = hashlib.blake2b(f"{path}\0{key}\0{n}".encode(), digest_size=8).digest()
    return np.uint64(int.from_bytes(digest, "little"))


def _uniforms(seed: int, samples: np.ndarray, site: np.uint64, stream: int) -> np.ndarray:
    """Uniform float64 in (0, 1), one per sample, of one stream of a site."""
    state = _mix(np.full(samples.shape, np.uint64(seed) ^ site, np.uint64))
    state = _mix(state ^ samples.astype(np.uint64))
    bits = _mix(state ^ np.uint64(stream))
    return ((bits >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0**-53


def units(func: str, seed: int, samples, path: str, key: str, n: int = 0) -> np.ndarray:
    """The unit deviates of the draws at site (`path`, `key`, `n`) for each sample index of
    `samples`: a standard normal z (`gauss`, `agauss`) or a uniform w on (-1, 1) (`unif`,
    `aunif`)."""
    samples = np.asarray(samples, np.int64)
    site = _site_bits(path, key, n)
    if func in ("gauss", "agauss"):
        u1, u2 = _uniforms(seed, samples, site, 1), _uniforms(seed, samples, site, 2)
        return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
    if func in ("unif", "aunif"):
        return 2.0 * _uniforms(seed, samples, site, 1) - 1.0
    raise TypeError(f"not a random function: {func}")


def values(func: str, args: list[float], seed: int, samples, path: str, key: str,
           n: int = 0) -> np.ndarray:
    """The draws of `func(*args)` (arguments already checked) at site (`path`, `key`, `n`)
    for each sample index of `samples`: nom + scale * `units` (gauss: scale |nom| rvar /
    sigma, agauss avar / sigma, unif |nom| rvar, aunif avar)."""
    unit = units(func, seed, samples, path, key, n)
    nom, spread = float(args[0]), float(args[1])
    if func in ("gauss", "agauss"):
        sigma = float(args[2]) if len(args) == 3 else 1.0
        scale = abs(nom) * spread if func == "gauss" else spread
        return nom + (scale / sigma) * unit
    half = abs(nom) * spread if func == "unif" else spread
    return nom + half * unit


@dataclass(frozen=True, slots=True)
class Sample:
    """One Monte Carlo sample: its index and the seed of the population; `log`, where given,
    collects every draw's (path, key, n, func, args) in the order drawn (for
    `springc.lang.variation`, which draws a whole population of an elaboration at once)."""

    index: int
    seed: int
    log: list | None = field(default=None, compare=False)


class Site:
    """Where random calls are being evaluated: the sample (None: nominal values), the
    instance or element `path` and the parameter or element `key` (None: a place that takes
    no random value, a bug of the elaborator if one is met there)."""

    __slots__ = ("count", "key", "path", "sample")

    def __init__(self, sample: Sample | None, path: str, key: str | None = None) -> None:
        self.sample, self.path, self.key = sample, path, key
        self.count = 0

    def keyed(self, key: str | None, path: str | None = None) -> Site:
        """A fresh site for the value of `key` (of `path`, default this site's)."""
        return Site(self.sample, self.path if path is None else path, key)

    def draw(self, func: str, args: list[float], loc: SourceLoc) -> float:
        """The value of the next random call of this site."""
        check_args(func, args, loc)
        if self.sample is None:
            return float(args[0])
        if self.key is None:
            raise TypeError(f"internal error: {func}() at {loc} evaluated outside a value")
        n, self.count = self.count, self.count + 1
        s = self.sample
        if s.log is not None:
            s.log.append((self.path, self.key, n, func, tuple(args)))
        return float(values(func, args, s.seed, [s.index], self.path, self.key, n)[0])

    def deviate(self, func: str, key: str, n: int) -> float:
        """The unit deviate of the `n`-th random call of `key`'s value at this site's path
        (`units`; 0 without a sample)."""
        if self.sample is None:
            return 0.0
        s = self.sample
        return float(units(func, s.seed, [s.index], self.path, key, n)[0])


def nominal(func: str, args: list[float], loc: SourceLoc) -> float:
    """The value of a random call outside any sample: its nominal value (arguments checked)."""
    check_args(func, args, loc)
    return float(args[0])
