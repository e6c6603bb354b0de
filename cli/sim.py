"""`springc sim`: simulate a netlist for one or many input signals."""

from __future__ import annotations

import click

from springc_cli.common import plot_option, precision_option, run_user_errors
from springc.integrators import TABLEAUX

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
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="out.npz (t, one (runs, T) array per probe, reductions, runs) or out.csv "
                   "(long format: run,quantity,t,value).")
@plot_option
@click.option("--tstep", type=float, help="Input grid step in seconds (overrides .tran).")
@click.option("--tstop", type=float, help="Stop time in seconds (overrides .tran).")
@click.option("--substeps", type=int, help="Integration steps per input sample (default 1).")
@precision_option
@click.option("--method", type=click.Choice(list(TABLEAUX)), default=None,
              help="Integrator (default: netlist option or rk4).")
@click.option("--outrate", type=float, help="Output sample rate in Hz (default 1/tstep).")
@click.option("--reduce", "reduce_", multiple=True, metavar="SPEC", help=REDUCE_HELP)
@click.option("--channel", type=int, default=None,
              help="File channel feeding in(0) (needed for stereo files).")
@click.option("--batch", type=int, default=None, help="Runs per kernel call (default 256).")
@run_user_errors
def sim_cmd(netlist, inputs, output, plot_path, tstep, tstop, substeps, precision, method,
            outrate, reduce_, channel, batch):
    """Simulate NETLIST for every input signal and write the probes and reductions.

    Runs are integrated together in lockstep by a kernel generated for the netlist; inputs
    are resampled to 1/tstep and interpolated linearly at the integrator's stage times."""
    from springc import results
    from springc.lang import load_file
    from springc.simulate import simulate

    results.check_output_path(output)
    net = load_file(netlist)
    res = simulate(net, list(inputs) or None, tstep=tstep, tstop=tstop, substeps=substeps,
                   method=method, precision=precision, outrate=outrate,
                   reductions=list(reduce_), batch=batch, channel=channel, progress=True)
    results.write(res, output)
    if plot_path:
        results.plot(res, plot_path)
    click.echo(f"{len(res.runs)} run(s), {len(res.t)} samples, {len(res.probes)} probe(s) "
               f"-> {output}" + (f", plot {plot_path}" if plot_path else ""))
