"""`springc export --spice`: a netlist as an ngspice circuit (force-current analogy), for
cross-checks with the most trusted circuit simulator."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click
from springc_cli.common import check_output_file, plot_option, run_user_errors

from springc.sim import sources
from springc.design.emit import write_atomic
from springc.errors import UsageError
from springc.export.spice import SpiceOptions, transient
from springc.lang.ir import FlatNetlist
from springc.export.ngspice import CrossCheck, cross_check, plot_cross_check


@click.command("export")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--spice", "spice", is_flag=True, help="Write an ngspice circuit (the only format).")
@click.option(
    "-o",
    "--output",
    type=click.Path(),
    required=True,
    help="Circuit file to write (e.g. out.cir); written atomically.",
)
@click.option("--tstep", type=float, default=None, help="Output step, s (default: .tran).")
@click.option("--tstop", type=float, default=None, help="Stop time, s (default: .tran).")
@click.option(
    "--tmax",
    type=float,
    default=None,
    help="Largest internal step of ngspice, s (default: the output step).",
)
@click.option(
    "--reltol",
    type=float,
    default=None,
    help="ngspice's relative tolerance (default 1e-6; 1e-9 with sampled inputs, which make "
    "ngspice restart its integration at every sample).",
)
@click.option(
    "--input",
    "input_path",
    type=click.Path(),
    default=None,
    help="Sound file whose channel k feeds in(k) (resampled to 1/tstep, inlined).",
)
@click.option(
    "--channel", type=int, default=None, help="Feed in(0) from this channel of --input instead."
)
@click.option(
    "--compare",
    is_flag=True,
    help="Also run the circuit in ngspice and the netlist in springc, and print the relative "
    "L2 difference of every probe and both wall times.",
)
@click.option("--substeps", type=int, default=None, help="springc substeps for --compare.")
@plot_option
@run_user_errors
def export_cmd(
    netlist,
    spice,
    output,
    tstep,
    tstop,
    tmax,
    reltol,
    input_path,
    channel,
    compare,
    substeps,
    plot_path,
) -> None:
    """Export NETLIST (.spr) to another simulator's format; with --spice, an ngspice circuit:
    velocities are node voltages, masses capacitors, springs inductors, dampers resistors,
    nonlinear forces B-sources. Run it with `ngspice -b OUT`; probes go to springc_probes.txt."""
    if not spice:
        raise UsageError("choose the output format: --spice (ngspice) is the one available")
    import springc

    for path in (output, plot_path):
        if path:
            check_output_file(path)
    if plot_path and not compare:  # before any work, so nothing is written
        raise UsageError("--plot shows the comparison: add --compare")
    net = springc.load(netlist)
    options = SpiceOptions(tstop=tstop, tstep=tstep, tmax=tmax, reltol=reltol)
    options = _bind_inputs(net.flat, options, input_path, channel)
    write_atomic(output, net.export_spice(**vars(options)))
    click.echo(f"wrote {output}", err=True)
    if compare:
        compared = cross_check(net.checked, options, substeps)
        click.echo(_summary(compared))
        if plot_path:
            plot_cross_check(compared, plot_path)
            click.echo(f"wrote {plot_path}", err=True)


def _summary(check: CrossCheck) -> str:
    """Per-probe differences and the two simulators' speeds, one line each."""
    lines = [
        f"{label}: relative L2 difference springc vs ngspice {err:.2e}"
        for label, err in check.errors.items()
    ]
    for name, seconds in (("ngspice", check.ngspice_seconds), ("springc", check.springc_seconds)):
        lines.append(f"{name}: {seconds:.3f} s wall, {seconds / check.tstop:.3g} s per simulated s")
    return "\n".join(lines)


def _bind_inputs(
    net: FlatNetlist, options: SpiceOptions, path: str | None, channel: int | None
) -> SpiceOptions:
    """The options with the --input file's channels bound to in(k), read as `springc sim`
    reads them (one run)."""
    if path is None:
        return options
    tstep, _, _ = transient(net, options)
    rate = 1.0 / tstep
    signals = sources.read_inputs([Path(path)], rate, sources.channels_used(net), channel)[0]
    return replace(options, inputs={k: (sig, rate) for k, sig in enumerate(signals)})
