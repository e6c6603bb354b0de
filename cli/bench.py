"""`springc bench`: speed against error on the reference networks (`springc.bench.suite`,
written by `springc.bench.report`), the same page rendered again from a stored bench.json
(`--render`), or the single-network kernel throughput table (`--issue3`,
`springc.bench.throughput`)."""

from __future__ import annotations

import time
from pathlib import Path

import click
from springc_cli.common import on_device, run_user_errors

RENDER_COMMAND = "springc bench --render docs/bench/bench.json --out docs"
CASE_NAMES = ("feature", "kws", "delay", "stiff", "duffing", "kws-features", "kws-classifier")


@click.command("bench")
@click.option("--case", "case_names", multiple=True, type=click.Choice(CASE_NAMES),
              help="Run only this reference network (repeatable; default: all).")
@click.option("--out", "outdir", type=click.Path(file_okay=False), default="bench-out",
              show_default=True,
              help="Folder for bench.md and bench/ (bench.json and <case>.png).")
@click.option("--quick", is_flag=True, help="Short workloads (checks the machinery only).")
@click.option("--render", "render_from", type=click.Path(), default=None,
              help="Measure nothing: write bench.md and the PNGs again from this bench.json "
                   f"(the committed page: `{RENDER_COMMAND}`).")
@click.option("--issue3", is_flag=True,
              help="Instead: the issue-3 kernel table on the 564-dof network (options below).")
@click.option("--seconds", type=float, default=1.0, show_default=True,
              help="--issue3: simulated seconds of noise input per kernel run.")
@click.option("--batch", type=int, default=64, show_default=True,
              help="--issue3: runs simulated together in the batched measurement.")
@click.option("--stretch", type=float, default=0.02, show_default=True,
              help="--issue3: simulated seconds for the slow peers (numpy, scipy).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              default="bench-out/bench.json", show_default=True,
              help="--issue3: where to write JSON.")
@click.option("--scaling", is_flag=True,
              help="Instead: time of each stage for chains and lattices of 10^3 to 10^6 "
                   "masses, and ngspice on the chain (springc.bench.scaling); writes "
                   "OUT/scaling.md, .json and .png. With --quick: 10^3 and 10^4, 100 steps.")
@click.option("--population", is_flag=True,
              help="Instead: 256 Monte Carlo samples of a 500-mass chain in the lanes of one "
                   "call against 256 runs of the nominal chain, and scipy per sample "
                   "(springc.bench.population); writes OUT/bench-population.md and "
                   "OUT/bench/population.json. With --quick: 50 masses, 32 samples.")
@click.option("--noise", is_flag=True,
              help="Instead: the 8x3 feature network with thermal noise on every damper "
                   "against without, alternating, and the noise's statistics "
                   "(springc.bench.noise); writes OUT/bench-noise.md and OUT/bench/noise.json. "
                   "With --quick: 8 runs of 0.02 s, a short oscillator.")
@click.option("--startup", is_flag=True,
              help="Instead: whole springc processes, build and sim of the example netlists, "
                   "the 564-dof network and the 8x3 classifier, warm and cold kernel cache, "
                   "beside `import numba`, a small function from numba's cache and ngspice "
                   "(springc.bench.startup); writes OUT/bench-startup.md and "
                   "OUT/bench/startup.json. With --quick: 2 warm runs and 1 cold run per row.")
@run_user_errors
@on_device
def bench_cmd(case_names, outdir, quick, render_from, issue3, seconds, batch, stretch,
              json_path, scaling, population, noise, startup):
    """Speed against error: on each reference network (feature extractor, 8x3 keyword
    spotter, long delay line, stiff all-to-all block, hard-driven Duffing resonator) every
    integrator at several steps and float64/float32, and the peers (scipy RK45/DOP853 at rtol
    1e-6, numpy RK4, ngspice when installed), with per-probe errors against a tight reference,
    wall, compile time, throughput and its fraction of the measured arithmetic ceiling and of
    the machine's FMA peak. Writes OUT/bench.md, OUT/bench/bench.json and OUT/bench/<case>.png;
    prints the Markdown. With --render, writes the same from a stored bench.json instead.
    With --device cuda, springc's kernels run in the CUDA form (the peers on the CPU; the
    ceiling and FMA peak stay the CPU's); the page names the device."""
    if issue3:
        _issue3(seconds, batch, stretch, json_path)
        return
    if scaling:
        _scaling(Path(outdir), quick)
        return
    if population:
        _population(Path(outdir), quick)
        return
    if noise:
        _noise(Path(outdir), quick)
        return
    if startup:
        _startup(Path(outdir), quick)
        return
    from springc.bench import report
    from springc.bench import suite as benchsuite
    from springc.sim import gpu

    if render_from is not None:
        _echo(report.render(Path(render_from), Path(outdir)))
        return

    machine = benchsuite.machine_info()
    machine["device"] = gpu.device_name()
    start = time.perf_counter()

    def say(message: str) -> None:  # elapsed time first: the suite runs for minutes
        click.echo(f"[{time.perf_counter() - start:6.0f} s] {message}", err=True)

    results = benchsuite.run_suite(list(case_names) or None, quick=quick, progress=say)
    machine["suite_wall_s"] = time.perf_counter() - start
    machine["load_end"] = benchsuite.machine_info()["load"]
    _echo(report.write_report(results, Path(outdir), machine))


def _echo(paths: dict[str, Path]) -> None:
    click.echo(paths["md"].read_text())
    click.echo(f"(written: {', '.join(str(p) for p in paths.values())})")


def _issue3(seconds, batch, stretch, json_path) -> None:
    from springc.bench.throughput import markdown, run_bench, write_json

    result = run_bench(seconds, batch, stretch, progress=lambda m: click.echo(m, err=True))
    write_json(result, json_path)
    click.echo(markdown(result))
    click.echo(f"\n(JSON: {json_path})")


def _population(outdir: Path, quick: bool) -> None:
    from springc.bench import population

    sizes = dict(masses=50, samples=32, tstop=0.1, scipy_samples=1) if quick else {}
    result = population.run_population(**sizes, progress=lambda m: click.echo(m, err=True))
    _echo(population.write_report(result, outdir))


def _noise(outdir: Path, quick: bool) -> None:
    from springc.bench import noise

    sizes = dict(runs=8, seconds=0.02, rounds=2, osc_runs=16, osc_tstop=200.0) if quick else {}
    result = noise.run_noise(**sizes, progress=lambda m: click.echo(m, err=True))
    _echo(noise.write_report(result, outdir))


def _startup(outdir: Path, quick: bool) -> None:
    from springc.bench import startup

    runs = dict(runs=2, cold_runs=1) if quick else {}
    result = startup.run_startup(**runs, progress=lambda m: click.echo(m, err=True))
    _echo(startup.write_report(result, outdir))


def _scaling(outdir: Path, quick: bool) -> None:
    from springc.bench import scaling

    sizes = scaling.SIZES[:2] if quick else scaling.SIZES
    result = scaling.run_scaling(sizes, 100 if quick else scaling.STEPS,
                                 thread_sizes=sizes[-1:] if quick else scaling.THREAD_SIZES,
                                 progress=lambda m: click.echo(m, err=True))
    _echo(scaling.write_report(result, outdir))
