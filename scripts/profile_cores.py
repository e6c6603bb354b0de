"""Regenerate docs/results-cores.md: how many cores `springc train` and `springc eval` of the
mass-spring keyword spotter keep busy, phase by phase.

    python scripts/profile_cores.py --data DIR --out /tmp/cores [-n 8 -m 3]

Runs `springc train --realisation mass-spring` and then `springc eval` of its model as a user
would (the installed `springc`, a fresh kernel and feature cache in OUT/cache, so compiles are
in), samples the machine's busy cores from /proc/stat every 0.25 s, and names the phase by the
last line the command wrote to stderr (a progress bar by its description). Per command: the
wall time, the mean busy cores, every phase with its share of the run and its mean busy
cores, the phases during which at most 1.25 cores were busy on average, and a PNG of the busy
cores over time (docs/results-cores.png, not committed). Measure on an otherwise quiet
machine: the sampler counts every process.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import platform
import pty
import shutil
import struct
import subprocess
import sys
import termios
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

INTERVAL = 0.25  # s between samples of /proc/stat
ONE_CORE = 1.25  # mean busy cores at or below which a phase counts as single-core
START = "start (imports, data, cluster)"


def cpu_times() -> tuple[int, int]:
    """(busy, total) jiffies of the whole machine since boot."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
    idle = fields[3] + fields[4]  # idle and iowait
    return sum(fields) - idle, sum(fields)


def label(line: str) -> str:
    """A phase's name: a progress bar's description, or the line itself (shortened)."""
    if "%|" in line and ":" in line:
        return line.split(":")[0].strip()
    return line.strip()[:80]


@dataclass
class Run:
    """A profiled command: busy cores per sample and the phase of each sample."""

    command: list[str]
    seconds: float = 0.0
    samples: list[tuple[float, float, str]] = field(default_factory=list)  # (t, cores, phase)

    def phases(self) -> list[tuple[str, float, float]]:
        """(phase, seconds, mean busy cores) in order; a line printed again later (the
        classifier's choice prints the features' lines) is a phase of its own."""
        spans: list[tuple[str, list[float]]] = []
        count: dict[str, int] = {}
        last = None
        for _, cores, phase in self.samples:
            if phase != last:
                count[phase] = count.get(phase, 0) + 1
                spans.append((phase if count[phase] == 1 else f"{phase} ({count[phase]})", []))
                last = phase
            spans[-1][1].append(cores)
        return [(p, len(c) * INTERVAL, sum(c) / len(c)) for p, c in spans]


def profile(command: list[str], env: dict) -> Run:
    """Run `command`, sampling the busy cores and reading its stderr for the phase (through a
    pseudo-terminal, so that it draws its progress bars as for a person)."""
    run = Run(command)
    phase = [START]
    master, slave = pty.openpty()
    # a terminal of 160 columns: with none (0 x 0) tqdm draws empty bars
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 50, 160, 0, 0))
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    reader = threading.Thread(target=_read_phases, args=(master, phase), daemon=True)
    reader.start()
    ncores = os.cpu_count() or 1
    start = time.perf_counter()
    busy, total = cpu_times()
    while proc.poll() is None:
        time.sleep(INTERVAL)
        b, t = cpu_times()
        if t > total:
            run.samples.append((time.perf_counter() - start, ncores * (b - busy) / (t - total),
                                phase[0]))
        busy, total = b, t
    run.seconds = time.perf_counter() - start
    reader.join(timeout=5)
    os.close(master)
    if proc.returncode:
        raise SystemExit(f"{' '.join(command)} failed with exit status {proc.returncode}")
    return run


def _read_phases(fd: int, phase: list[str]) -> None:
    """Keep phase[0] at the label of the last line (split at \r and \n) read from `fd`."""
    line = ""
    while True:
        try:
            chunk = os.read(fd, 4096).decode(errors="replace")
        except OSError:  # the command has ended and closed its end
            return
        if not chunk:
            return
        for char in chunk:
            if char in "\r\n":
                if line.strip():
                    phase[0] = label(line)
                line = ""
            else:
                line += char


def table(run: Run) -> list[str]:
    """Markdown rows: every phase of at least 1% of the run."""
    rows = ["| phase | wall s | share | busy cores |", "|---|---|---|---|"]
    for phase, sec, cores in run.phases():
        if sec >= 0.01 * run.seconds:
            rows.append(f"| {phase.replace('|', '/')} | {sec:.1f} | {sec / run.seconds:.0%} | "
                        f"{cores:.2f} |")
    return rows


def single_core(run: Run) -> list[tuple[str, float]]:
    """(phase, share of the run) of the phases at most ONE_CORE busy on average."""
    return [(p, sec / run.seconds) for p, sec, cores in run.phases() if cores <= ONE_CORE]


def plot(runs: list[Run], path: Path) -> None:
    """Busy cores over time, one panel per command."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 3 * len(runs)), squeeze=False)
    for ax, run in zip(axes[:, 0], runs):
        t = [s[0] for s in run.samples]
        ax.plot(t, [s[1] for s in run.samples], lw=0.8)
        ax.axhline(ONE_CORE, color="grey", ls=":", lw=0.8)
        ax.set_ylim(0, (os.cpu_count() or 1) + 0.2)
        ax.set_ylabel("busy cores")
        ax.set_title(" ".join(["springc", *run.command[1:3]]), fontsize=9)
        last = None
        for when, _, phase in run.samples:
            if phase != last:
                ax.axvline(when, color="red", lw=0.4, alpha=0.5)
                last = phase
    axes[-1, 0].set_xlabel("seconds since the command started")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def corpus_size(data: Path) -> str:
    """'N clips' of the folder's wav files."""
    return f"{sum(1 for _ in data.rglob('*.wav'))} wav files"


def markdown(runs: list[Run], args: argparse.Namespace) -> str:
    """docs/results-cores.md: the plot, the phases of each command, then how it was
    measured."""
    lines = [
        "# Busy cores in mass-spring training and evaluation",
        "",
        "Plot: `results-cores.png` beside this page after a run (not committed; phase changes "
        "in red).",
        "",
    ]
    for run in runs:
        lines += _run_section(run)
    lines += [
        "## How it was measured",
        "",
        f"Generated by `python scripts/profile_cores.py --data DIR -n {args.bins} -m "
        f"{args.delays}` on {platform.machine()}, {os.cpu_count()} cores (DIR: "
        f"`{args.data.name}`, {corpus_size(args.data)}); empty kernel and feature cache, so the "
        "compiles are in. Busy cores: the whole machine's, from /proc/stat every "
        f"{INTERVAL} s; a phase is the last line the command wrote to stderr (a progress "
        "bar by its description).",
        "",
    ]
    return "\n".join(lines)


def _run_section(run: Run) -> list[str]:
    """One command's section: its time and mean busy cores, its phases' table and the phases
    at most ONE_CORE cores busy."""
    cores = sum(s[1] for s in run.samples) / max(len(run.samples), 1)
    lines = [f"## `springc {' '.join(run.command[1:2])}`", "",
             f"{run.seconds:.1f} s, {cores:.2f} cores busy on average.", ""]
    lines += table(run)
    one = single_core(run)
    worst = max((share for _, share in one), default=0.0)
    lines += ["", f"Phases at most {ONE_CORE} cores busy: "
              + ("; ".join(f"{p} ({share:.0%})" for p, share in one) or "none")
              + f". Longest: {worst:.0%} of the run (target: at most 10%).", ""]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("/tmp/cores"))
    parser.add_argument("-n", "--bins", type=int, default=8)
    parser.add_argument("-m", "--delays", type=int, default=3)
    parser.add_argument("--doc", type=Path, default=Path(__file__).resolve().parents[1]
                        / "docs" / "results-cores.md")
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    args.out.mkdir(parents=True)
    env = {**os.environ, "SPRINGC_CACHE": str(args.out / "cache")}
    model = args.out / "model"
    runs = [profile(["springc", "train", "--data", str(args.data), "-n", str(args.bins),
                     "-m", str(args.delays), "--realisation", "mass-spring", "-o", str(model)],
                    env),
            profile(["springc", "eval", str(model)], env)]
    plot(runs, args.doc.with_suffix(".png"))
    args.doc.write_text(markdown(runs, args))
    print(f"written: {args.doc}", file=sys.stderr)


if __name__ == "__main__":
    main()
