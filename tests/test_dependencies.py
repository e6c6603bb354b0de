"""Every third-party module the sources import is declared in pyproject.toml: `springc/` and
`cli/` against `[project] dependencies`, `tests/` and `scripts/` against those plus the `dev`
extra. Lazy imports inside functions count: a fresh machine installs only what is declared."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT = {"springc", "springc_cli", "cli", "tests", "conftest"}
# import names that differ from the distribution's name
ALIAS = {"sklearn": "scikit-learn", "soundfile": "soundfile", "yaml": "pyyaml", "PIL": "pillow",
         "nvidia": "nvidia-cuda-nvcc-cu12"}


def normalise(name: str) -> str:
    """A distribution name as PEP 503 compares them."""
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_names(requirements: list[str]) -> set[str]:
    """The distribution names of PEP 508 requirement strings (extras and versions dropped)."""
    return {normalise(re.match(r"[A-Za-z0-9._-]+", r.strip()).group(0)) for r in requirements}


def declared(pyproject: Path, extras: tuple[str, ...] = ()) -> set[str]:
    """The distributions pyproject.toml declares: its dependencies plus the named extras."""
    project = tomllib.loads(pyproject.read_text())["project"]
    names = requirement_names(project.get("dependencies", []))
    for extra in extras:
        names |= requirement_names(project.get("optional-dependencies", {}).get(extra, []))
    return names


def imported_modules(source: str) -> set[str]:
    """Top-level names of every absolute import in `source`, nested ones included."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module.split(".")[0])
    return names


def undeclared(folders: list[Path], allowed: set[str]) -> dict[str, list[str]]:
    """Third-party modules imported under `folders` whose distribution is not in `allowed`,
    each with the files that import it."""
    found: dict[str, list[str]] = {}
    local = {path.stem for folder in folders for path in folder.rglob("*.py")}
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            for name in imported_modules(path.read_text()):
                if name in sys.stdlib_module_names or name in PROJECT | local:
                    continue
                if normalise(ALIAS.get(name, name)) not in allowed:
                    found.setdefault(name, []).append(str(path.relative_to(folder.parent)))
    return found


def test_the_package_imports_only_declared_dependencies() -> None:
    allowed = declared(ROOT / "pyproject.toml")
    assert undeclared([ROOT / "springc", ROOT / "cli"], allowed) == {}


def test_tests_and_scripts_import_only_declared_dependencies() -> None:
    allowed = declared(ROOT / "pyproject.toml", extras=("dev",))
    # the extras gpu-peers (jax, diffrax) and cuda-offline (NVIDIA's compiler) serve one
    # script each
    peers = declared(ROOT / "pyproject.toml", extras=("gpu-peers",)) - allowed
    offline = {"nvidia"}  # the import name of cuda-offline's nvidia-cuda-nvcc-cu12
    assert declared(ROOT / "pyproject.toml", extras=("cuda-offline",)) >= {
        normalise(ALIAS[name]) for name in offline}
    assert undeclared([ROOT / "tests", ROOT / "scripts"], allowed) == {
        **{name: ["scripts/gpu_peers.py"] for name in sorted(peers)},
        **{name: ["scripts/cuda_resources.py"] for name in offline}}


def test_an_undeclared_lazy_import_is_found(tmp_path: Path) -> None:
    (tmp_path / "pyproject.toml").write_text(
        '[project]\nname = "x"\ndependencies = ["numpy>=1", "dask[distributed]>=2024",'
        ' "scikit-learn"]\n')
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "a.py").write_text(
        "import os\nimport numpy as np\nfrom sklearn import svm\nfrom . import b\n"
        "def f():\n    from dask.distributed import Client\n    import torch.nn\n")
    found = undeclared([package], declared(tmp_path / "pyproject.toml"))
    assert found == {"torch": ["pkg/a.py"]}
