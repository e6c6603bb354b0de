"""Do an old commit and this working tree simulate bitwise alike?

    python scripts/bitwise_check.py OLD_COMMIT [--steps N] [--jobs J] [--only TEXT] [--keep]

Checks OLD_COMMIT out into a temporary `git worktree` and simulates the same workloads with
each tree, every simulation in its own subprocess (PYTHONPATH: that tree and a `springc_cli`
link to its `cli/`; SPRINGC_CACHE: a fresh folder per tree):

- every netlist in netlists/examples/*.spr and tests/cases/ok/*.spr (this tree's files, read
  by both; plus `DERIVED` copies, such as elements.spr with a sign `check` accepts) through
  each tree's `springc sim` CLI, once per kernel form (`--kernel auto`, `shared`,
  `written-out`), every run recording its probes and its final state (`final:x`, `final:v`
  of up to 12 nodes, `energy`), and again with accumulated reductions (`dissipated:all`,
  and `work:in` where the netlist reads in(k)) in the shared and the written-out form (per
  node: register kernels accumulate none): at most N steps (default 2000) of its `.tran`
  (tstep 0.1 ms for 0.05 s where it has none), two runs of a deterministic input where it
  reads in(k);
- every bench case of `cases(quick=True)` (springc/bench/suite.py; springc/benchsuite.py
  before the package split): each (method, substeps, precision) row the case applies, in the
  form simulate picks, and each rk4 row again written out.

Every array of both results (t, each probe, each reduction) is compared bitwise: same dtype,
same shape, same bytes (so NaN positions and signed zeros count). A workload that fails in
both trees is equal when both fail with the same kind of error. Prints a Markdown table:
case, arrays, max |diff|, equal; exit status 1 when something differs.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NETLISTS = ("netlists/examples/*.spr", "tests/cases/ok/*.spr")
FORMS = ("auto", "shared", "written-out")
NO_TRAN = (1e-4, 0.05)  # tstep, tstop for a netlist without .tran
RATE = 48000  # Hz: the sample rate of the input files (each tree resamples them alike)
# netlist -> (text, replacement, why): a copy simulated as well, for what the file's own
# text cannot show (elements.spr is the only netlist with every element kind, P terms
# included, but `check` refuses its Q1, so its own runs stop at the check in a new tree)
DERIVED = {"tests/cases/ok/elements.spr": ("Q1 a b g=1.5 a=-1", "Q1 a b g=1.5 a=1",
                                           "Q1 a=1")}

# One bench workload in the tree on sys.path: the case's network, inputs and one row.
BENCH_DRIVER = r"""
import sys, numpy as np
name, method, sub, precision, write_out, out = sys.argv[1:]
try:
    from springc.bench.suite import cases
    from springc.sim.simulate import simulate
    prepare = lambda case: case.checked
    extra = {"check_step": False}
except ImportError:  # before the package split: simulate took the FlatNetlist
    from springc.benchsuite import cases
    from springc.simulate import simulate
    prepare = lambda case: case.net
    extra = {}
case = next(c for c in cases(quick=True) if c.name == name)
res = simulate(prepare(case), case.inputs, tstep=case.tstep, tstop=case.tstop,
               substeps=int(sub), method=method, precision=precision,
               write_out={"auto": None, "written-out": True}[write_out], **extra)
arrays = {"t": res.t}
arrays.update({"probe " + k: v for k, v in res.probes.items()})
arrays.update({"reduce " + k: v for k, v in res.reductions.items()})
np.savez(out, **arrays)
"""

# The bench workloads of the tree on sys.path: (case, method, substeps, precision) per row.
BENCH_LIST = r"""
import json
try:
    from springc.bench.suite import _applies, cases
except ImportError:
    from springc.benchsuite import _applies, cases
rows = []
for case in cases(quick=True):
    for method, sub, precision in dict.fromkeys(case.configs):
        if _applies(case, method):
            rows.append((case.name, method, sub, precision))
print(json.dumps(rows))
"""

CLI = "import sys; from springc_cli.main import main; sys.argv[0] = 'springc'; main()"


@dataclass
class Tree:
    """A source tree and how a subprocess runs it."""

    label: str
    root: Path
    work: Path

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(self.root), str(self.work / "shim")])
        env["SPRINGC_CACHE"] = str(self.work / "cache")
        env["PYTHONHASHSEED"] = "0"
        return env

    def prepare(self) -> None:
        (self.work / "shim").mkdir(parents=True, exist_ok=True)
        (self.work / "cache").mkdir(exist_ok=True)
        link = self.work / "shim" / "springc_cli"
        if not link.exists():
            link.symlink_to(self.root / "cli", target_is_directory=True)
        where = self.run(["-c", "import springc, springc_cli; "
                          "print(springc.__file__); print(springc_cli.__file__)"])
        for line in where.stdout.split():
            if not Path(line).resolve().is_relative_to(self.root.resolve()):
                raise SystemExit(f"{self.label}: imported {line}, not from {self.root}")

    def run(self, args: list[str], timeout: float = 900) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, *args], env=self.env(), cwd=self.work,
                              capture_output=True, text=True, timeout=timeout)


@dataclass
class Workload:
    """One simulation, run in both trees: `args(tree, out)` is its subprocess command."""

    case: str
    args: object


def netlist_workloads(steps: int, inputs: Path) -> list[Workload]:
    """`springc sim` on every example and golden netlist, per kernel form and reductions."""
    sys.path.insert(0, str(ROOT))
    from springc.lang import load_file
    from springc.sim.sources import channels_used

    out = []
    paths = [(p, str(p.relative_to(ROOT))) for pat in NETLISTS for p in sorted(ROOT.glob(pat))]
    for rel, (old, new, why) in DERIVED.items():
        copy = inputs.parent / "derived" / Path(rel).name
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy.write_text((ROOT / rel).read_text().replace(old, new))
        paths.append((copy, f"{rel} ({why})"))
    for path, name in paths:
        net = load_file(path)
        tstep, tstop = (net.tran.tstep, net.tran.tstop) if net.tran else NO_TRAN
        chans = channels_used(net)
        base = ["sim", str(path), "--tstep", repr(tstep),
                "--tstop", repr(min(tstop, steps * tstep))]
        if chans:
            base += ["-i", str(_input_folder(inputs, chans))]
        state = _final_state(net.nodes)
        reduce = ["--reduce", "dissipated:all"] + (["--reduce", "work:in"] if chans else [])
        variants = [(f"--kernel {f}", state + ["--kernel", f]) for f in FORMS]
        variants += [(f"reductions {f}", state + reduce + ["--kernel", f])
                         for f in FORMS[1:]]
        for label, extra in variants:
            out.append(Workload(f"{name} {label}", _cli(base + extra)))
    return out


def _final_state(nodes: list[str], most: int = 12) -> list[str]:
    """Reductions of the final state (x and v of the first and last nodes, and the energy),
    so that a netlist without probes is compared too; they leave the kernel form as it is."""
    chosen = nodes if len(nodes) <= most else nodes[: most // 2] + nodes[-most // 2:]
    out = ["--reduce", "energy"]
    for node in chosen:
        out += ["--reduce", f"final:x({node})", "--reduce", f"final:v({node})"]
    return out


def _cli(args: list[str]):
    return lambda tree, npz: ["-c", CLI, *args, "-o", str(npz)]


def _input_folder(inputs: Path, channels: int) -> Path:
    """Two deterministic sound files of `channels` channels (a chirp plus noise)."""
    import soundfile

    folder = inputs / f"ch{channels}"
    if folder.exists():
        return folder
    folder.mkdir(parents=True)
    t = np.arange(RATE) / RATE
    for run in range(2):
        rng = np.random.default_rng(run)
        sig = np.stack([0.5 * np.sin(2 * np.pi * (50 + 400 * c + 2000 * t) * t + run)
                        + 0.1 * rng.standard_normal(len(t)) for c in range(channels)], 1)
        soundfile.write(folder / f"run{run}.wav", sig, RATE, subtype="FLOAT")
    return folder


def bench_workloads(tree: Tree) -> list[Workload]:
    """Every row of every quick bench case, as the tree lists them; rk4 rows also written
    out."""
    done = tree.run(["-c", BENCH_LIST])
    if done.returncode:
        raise SystemExit(f"{tree.label}: listing bench cases failed:\n{done.stderr}")
    out = []
    for name, method, sub, precision in json.loads(done.stdout):
        forms = ("auto", "written-out") if method == "rk4" else ("auto",)
        for form in forms:
            args = [name, method, str(sub), precision, form]
            out.append(Workload(f"bench {name} {method} x{sub} {precision} {form}",
                                _bench(args)))
    return out


def _bench(args: list[str]):
    return lambda tree, npz: ["-c", BENCH_DRIVER, *args, str(npz)]


def run_both(work: Workload, trees: tuple[Tree, Tree], index: int) -> dict:
    """Run one workload in both trees and compare the results."""
    results = []
    for tree in trees:
        npz = tree.work / "out" / f"{index}.npz"
        npz.parent.mkdir(exist_ok=True)
        done = tree.run(work.args(tree, npz))
        results.append((done, npz))
    return compare(work.case, *results)


def compare(case: str, old, new) -> dict:
    """The table row of one workload: arrays compared, max |diff|, equal or why not."""
    (done_old, npz_old), (done_new, npz_new) = old, new
    if done_old.returncode or done_new.returncode:
        why = [_error(d) for d in (done_old, done_new)]
        same = bool(done_old.returncode and done_new.returncode) and why[0][0] == why[1][0]
        return {"case": case, "arrays": 0, "diff": "", "equal": same,
                "note": f"old: {why[0][1]} / new: {why[1][1]}"}
    a, b = np.load(npz_old), np.load(npz_new)
    keys = sorted(set(a.files) | set(b.files))
    diff, equal, note = 0.0, True, []
    for key in keys:
        if key not in a.files or key not in b.files:
            equal = False
            note.append(f"{key} only in {'new' if key in b.files else 'old'}")
            continue
        x, y = a[key], b[key]
        if x.dtype != y.dtype or x.shape != y.shape:
            equal = False
            note.append(f"{key}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
            continue
        if x.tobytes() != y.tobytes():
            equal = False
            note.append(f"{key} differs")
        if x.dtype.kind in "fc" and x.size:
            d = np.abs(x.astype(np.float64) - y.astype(np.float64))
            d = d[~(np.isnan(x) & np.isnan(y))]
            diff = max(diff, float(np.nanmax(d, initial=0.0)))
    return {"case": case, "arrays": len(keys), "diff": f"{diff:.3g}", "equal": equal,
            "note": "; ".join(note)}


def _error(done: subprocess.CompletedProcess) -> tuple[str, str]:
    """(kind, one line) of a failed subprocess's error."""
    if not done.returncode:
        return "ok", "ran"
    lines = [ln for ln in done.stderr.strip().splitlines() if ln.strip()]
    raised = [ln for ln in lines if re.match(r"\w+(Error|Exception)\b", ln)]  # a traceback's
    located = [ln for ln in lines if "error:" in ln]  # a user error: its located message
    last = (raised[-1:] or located[:1] or lines[-1:] or [f"exit {done.returncode}"])[0]
    kind = re.match(r"(\w+(Error|Exception))|(.*error:)", last)
    short = re.sub(r"\s+", " ", last)[:110]
    return (kind.group(0) if kind else "error"), short


def table(rows: list[dict]) -> str:
    out = ["| case | arrays | max abs diff | equal | note |", "|---|---|---|---|---|"]
    for r in rows:
        note = r["note"].replace("|", "/")
        out.append(f"| {r['case']} | {r['arrays']} | {r['diff']} | "
                   f"{'yes' if r['equal'] else 'NO'} | {note} |")
    return "\n".join(out)


def worktree(commit: str, where: Path) -> Path:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(where), commit],
                   check=True, capture_output=True)
    return where


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("commit")
    p.add_argument("--steps", type=int, default=2000, help="most steps of a netlist's .tran")
    p.add_argument("--jobs", type=int, default=1, help="workloads run at the same time")
    p.add_argument("--only", default="", help="only workloads whose name contains this")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bitwise-"))
    try:
        old = Tree("old", worktree(args.commit, tmp / "old-tree"), tmp / "old")
        new = Tree("new", ROOT, tmp / "new")
        for tree in (old, new):
            tree.prepare()
        works = netlist_workloads(args.steps, tmp / "inputs") + bench_workloads(new)
        works = [w for w in works if args.only in w.case]
        with ThreadPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(lambda iw: run_both(iw[1], (old, new), iw[0]),
                                 enumerate(works)))
        print(table(rows))
        return 0 if all(r["equal"] for r in rows) else 1
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                        str(tmp / "old-tree")], capture_output=True)
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
