"""scripts/pytest_compilelog.py's summary: each kernel counted once, at its compile (its
longest entry), not at a later process's load of it, and credited to the test that compiled
it."""

import importlib.util
import json
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "pytest_compilelog.py"


def _module():
    spec = importlib.util.spec_from_file_location("pytest_compilelog", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_each_kernel_counts_once_for_the_test_that_compiled_it(tmp_path):
    entries = [("tests/test_a.py::one", "k1.py", 5.0), ("tests/test_b.py::two", "k1.py", 0.1),
               ("tests/test_b.py::two", "k2.py", 2.0), ("tests/test_b.py::three", "k3.py", 1.5)]
    log = tmp_path / "compiles.jsonl"
    log.write_text("".join(json.dumps({"test": t, "path": p, "s": s}) + "\n"
                           for t, p, s in entries))
    lines = _module().summary(str(log)).splitlines()
    assert lines[0] == "3 kernels, 8.5 s of compiling"
    assert lines[1].split() == ["5.0", "s", "1", "tests/test_a.py"]
    assert lines[2].split() == ["3.5", "s", "2", "tests/test_b.py"]
