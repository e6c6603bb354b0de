"""`springc sim`: simulate a netlist for one or many input signals."""

from __future__ import annotations

import click
from springc_cli.common import (DEVICES, check_output_file, plot_option, precision_option,
                                run_user_errors)

from springc.kernels.expint import SCHEMES
from springc.kernels.integrators import TABLEAUX
from springc.sim.plan import KERNEL_FORMS

REDUCE_HELP = (
    "Streaming reduction (repeatable), stored under its text: final:x(N) | final:v(N) | "
    "msq:x(N)[:T0:T1] (mean square over T0 < t <= T1) | work:in | work:FNAME (input work, "
    "integral of F v) | dissipated:all | dissipated:NAME (M or B element, or node) | "
    "energy (final total energy) | loss:NAME (insertion loss, dB: -10 log10(dissipated/work))."
)


@click.command("sim")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--input", "-i", "inputs", multiple=True, metavar="FILE-OR-DIR",
              help="Sound file (wav, flac, ogg; any rate) for in(k); a folder adds its sound "
                   "files in sorted order. Repeatable; each file is one run.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="out.npz (t, one (runs, T) array per probe, reductions, runs) or out.csv "
                   "(long format: run,quantity,t,value).")
@plot_option
@click.option("--tstep", type=float, help="Input grid step in seconds (overrides .tran).")
@click.option("--tstop", type=float, help="Stop time in seconds (overrides .tran).")
@click.option("--substeps", type=int,
              help="Integration steps per input sample (default: .options substeps=, else "
                   "chosen for --tolerance 1e-3; 1 with --method).")
@precision_option
@click.option("--method", type=click.Choice([*TABLEAUX, *SCHEMES]), default=None,
              help="Integrator (default: the netlist's .options method=, else chosen for "
                   "--tolerance 1e-3); the split schemes strang-rk4, exp-rk4 and exp-heun3 "
                   "propagate the driven linear filter blocks exactly and the rest with RK4 "
                   "(Heun3: three stages).")
@click.option("--tolerance", type=float, default=None,
              help="Pick the cheapest integrator and substeps whose estimated per-mode error "
                   "(relative L2, modes up to the input Nyquist frequency) is at most this; "
                   "on a netlist with nonlinear terms, raise the substeps until step doubling "
                   "over the first run's start agrees; prints the choice. The default "
                   "(1e-3) where neither the options nor the netlist name the integrator. "
                   "Not with --method/--substeps.")
@click.option("--outrate", type=float, help="Output sample rate in Hz (default 1/tstep).")
@click.option("--reduce", "reduce_", multiple=True, metavar="SPEC", help=REDUCE_HELP)
@click.option("--channel", type=int, default=None,
              help="File channel feeding in(0) (needed for stereo files).")
@click.option("--batch", type=click.IntRange(min=1), default=None,
              help="Runs per kernel call (default 256).")
@click.option("--kernel", "kernel_form", type=click.Choice(sorted(KERNEL_FORMS)),
              default="auto",
              help="auto: the force code written out (each run's step in registers where it "
                   "serves) for long simulations of at most 48 masses and for single runs of "
                   "up to 8, else one kernel shared by every netlist of the same element "
                   "kinds; written-out: always where it serves (compiled once per netlist "
                   "structure: for sweeps of short runs); shared: never.")
@click.option("--device", type=DEVICES, default="cpu",
              help="cpu: the CPU kernels; cuda: the CUDA kernel form, one run per GPU thread "
                   "(a block of threads per run above 48 masses; Runge-Kutta and Lawson; needs "
                   "springc[cuda] and an NVIDIA GPU); auto: cuda where a GPU is present and "
                   "serves the method, else cpu.")
@click.option("--fma/--no-fma", default=True,
              help="--no-fma: round every product and sum on its own, none fused into one "
                   "fused multiply-add, on the CPU and the GPU alike, so that --device cpu and "
                   "cuda give the same bits; no more accurate.")
@click.option("--temp", type=float, default=None,
              help="Temperature in kelvin of every damper's thermal noise force, drawn per "
                   "integration step (overrides .options temp=; 0: no noise).")
@click.option("--seed", type=int, default=None,
              help="Seed of the noise draws (overrides .options seed=; default 0). A run's "
                   "noise depends on the seed and its index only, not on --batch or --kernel.")
@click.option("--stats", is_flag=True,
              help="With .mc and --reduce: per reduction the mean, standard deviation, "
                   "5/50/95% quantiles, min and max over the samples, beside the first-order "
                   "prediction of the deviation from the gradient at the nominal design; "
                   "--plot then writes their histograms.")
@run_user_errors
def sim_cmd(netlist, inputs, output, plot_path, tstep, tstop, substeps, precision, method,
            outrate, reduce_, channel, batch, tolerance, kernel_form, temp, seed, device,
            stats, fma):
    """Simulate NETLIST for every input signal and write the probes and reductions.

    Runs are integrated together in lockstep by a kernel generated for the netlist; inputs
    are resampled to 1/tstep and interpolated linearly at the integrator's stage times.
    Without --method/--substeps (here or in the netlist's .options), springc chooses the
    cheapest integrator whose estimated error is at most 1e-3 (--tolerance) and prints it.

    With .step/.mc every point is simulated: probes (points, runs, T), reductions
    (points, runs) and the points' table in the output."""
    import springc
    from springc.errors import UsageError
    from springc.sim import results

    if stats and not reduce_:
        raise UsageError("--stats needs --reduce SPEC: the statistics are of reductions")
    results.check_output_path(output)
    for path in (output, plot_path):  # a failed command leaves no output: check both first
        if path:
            check_output_file(path, make_parents=True)
    # a step springc chooses is judged when it is taken; one the user pins, at load
    # (--tolerance chooses whatever the netlist's .options say)
    net = springc.load(netlist, method=method, tstep=tstep, substeps=substeps,
                       judge_step=False if tolerance is not None else None)
    if stats and net.variation.samples is None:
        raise UsageError(f"--stats: {netlist} has no .mc line, so no samples",
                         hint="add .mc N [seed=S] and random functions (gauss, agauss, ...)")
    res = net.simulate(list(inputs) or None, tstep=tstep, tstop=tstop, substeps=substeps,
                       method=method, tolerance=tolerance, precision=precision,
                       outrate=outrate, reduce=list(reduce_), batch=batch, channel=channel,
                       progress=True, kernel=kernel_form, device=device, temp=temp, seed=seed,
                       fma=fma)
    if res.choice:
        click.echo(res.choice)
    report = res.stats() if stats else None  # its errors come before any output
    res.save(output)
    if plot_path and report is not None:
        results.save_figure(report.figure(), plot_path)
    elif plot_path:
        res.plot(plot_path)
    if report is not None:
        click.echo(report.text())
    points = f"{len(res.points)} point(s) x " if res.points else ""
    click.echo(f"{points}{len(res.runs)} run(s), {len(res.t)} samples, {len(res.probes)} "
               f"probe(s) -> {output}" + (f", plot {plot_path}" if plot_path else ""))
