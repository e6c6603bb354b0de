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
    help="Circuit file to write (e.g. out.cir); written atomically. With .step/.mc, one "
    "file per point: out.p0.cir, out.p1.cir, ...",
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
    nonlinear forces B-sources. Run it with `ngspice -b OUT`; probes go to springc_probes.txt.

    With .step/.mc, one circuit per point with its values written in (ngspice's .step-free
    form), OUT's name with the point index before the suffix (out.cir: out.p0.cir,
    out.p1.cir, ...), each headed by a comment naming the point; not with --compare."""
    if not spice:
        raise UsageError("choose the output format: --spice (ngspice) is the one available")
    import springc

    for path in (output, plot_path):
        if path:
            check_output_file(path)
    if plot_path and not compare:  # before any work, so nothing is written
        raise UsageError("--plot shows the comparison: add --compare")
    net = springc.load(netlist)
    if net.variation.varies and compare:
        raise UsageError("--compare runs one circuit: not with .step/.mc",
                         hint="export without --compare (one circuit per point)")
    options = SpiceOptions(tstop=tstop, tstep=tstep, tmax=tmax, reltol=reltol)
    options = _bind_inputs(net.flat, options, input_path, channel)
    circuits = net.export_spice(**vars(options))  # all of them before any file is written
    if isinstance(circuits, str):
        write_atomic(output, circuits)
        click.echo(f"wrote {output}", err=True)
    else:
        paths = point_paths(output, len(circuits))
        for path in paths:
            check_output_file(path)
        for path, text in zip(paths, circuits):
            write_atomic(path, text)
        click.echo(f"wrote {len(paths)} circuits, one per point: {paths[0]} ... {paths[-1]}",
                   err=True)
    if compare:
        compared = cross_check(net.checked, options, substeps)
        click.echo(_summary(compared))
        if plot_path:
            plot_cross_check(compared, plot_path)
            click.echo(f"wrote {plot_path}", err=True)


def point_paths(output: str | Path, count: int) -> list[Path]:
    """The file of each point: OUT's name with `.p<index>` before its suffix."""
    out = Path(output)
    return [out.with_name(f"{out.stem}.p{i}{out.suffix}") for i in range(count)]


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
