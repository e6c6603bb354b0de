"""A pytest plugin that logs every kernel compile of a test run, and its summary.

Cold test time is mostly numba compiling kernels (docs/performance.md, "Cold-cache compiles").
A test change saves time only if it takes a kernel out of the whole suite: a kernel that one
test stops compiling but another still compiles has only moved. Run the suite on an empty
cache with the plugin, change, run again, and compare the summaries:

    SPRINGC_CACHE=$(mktemp -d) COMPILELOG=compiles.jsonl PYTHONPATH=scripts \\
        python -m pytest -p pytest_compilelog -n auto --dist loadfile
    python scripts/pytest_compilelog.py compiles.jsonl

Each line of the log is one entry into `loader.compiling` (a kernel's first call in a
process): the test, the kernel file, the seconds (a wait for another process's compile of
the same kernel included), its lines and its options line.
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import sys
import time

_CURRENT = {"test": None}


def pytest_configure(config) -> None:
    """Wrap `loader.compiling` where the kernel loaders call it."""
    from springc.grad import lanes
    from springc.kernels import loader

    inner = loader.compiling
    out = os.environ.get("COMPILELOG", "compiles.jsonl")

    @contextlib.contextmanager
    def logged(path):
        start = time.perf_counter()
        with inner(path):
            yield
        text = open(path).read()
        entry = {"test": _CURRENT["test"], "path": str(path), "pid": os.getpid(),
                 "s": time.perf_counter() - start, "lines": text.count("\n"),
                 "options": text.splitlines()[1][:200]}
        with open(out, "a") as fh:
            fh.write(json.dumps(entry) + "\n")

    loader.compiling = logged
    lanes.compiling = logged


def pytest_runtest_setup(item) -> None:
    _CURRENT["test"] = item.nodeid


def summary(path: str) -> str:
    """Distinct kernels (each at its longest entry: the compile, not a later load), their
    compile seconds in all, and per test file."""
    kernels: dict[str, dict] = {}
    for line in open(path):
        entry = json.loads(line)
        if entry["s"] > kernels.get(entry["path"], {"s": -1.0})["s"]:
            kernels[entry["path"]] = entry
    per_file = collections.Counter()
    count = collections.Counter()
    for k in kernels.values():
        name = (k["test"] or "?").split("::")[0]
        per_file[name] += k["s"]
        count[name] += 1
    rows = [f"{len(kernels)} kernels, {sum(per_file.values()):.1f} s of compiling"]
    rows += [f"{s:7.1f} s {count[name]:4d}  {name}" for name, s in per_file.most_common()]
    return "\n".join(rows)


if __name__ == "__main__":
    print(summary(sys.argv[1]))
