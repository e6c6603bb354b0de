"""`springc ac` (frequency response) and `springc modes` (eigenmodes) of the linearisation."""

from __future__ import annotations

import json

import click
from springc_cli.common import check_output_file, plot_option, run_user_errors


@click.command("ac")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--node", default=None, help="Output node (default: the .ac directive's).")
@click.option("--input", "channel", type=int, default=None,
              help="Input channel k of the F ... in(k) elements (default: .ac's, else 0).")
@click.option("--fmin", type=float, default=None, help="Lowest frequency, Hz.")
@click.option("--fmax", type=float, default=None, help="Highest frequency, Hz.")
@click.option("--points", type=int, default=None, help="Number of log-spaced frequencies.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="CSV file: f_hz,mag,phase_rad. With .step/.mc, one curve per point in "
                   "long format: point, the stepped parameters, sample and seed (with .mc), "
                   "then f_hz,mag,phase_rad.")
@plot_option
@run_user_errors
def ac_cmd(netlist, node, channel, fmin, fmax, points, output, plot_path) -> None:
    """Frequency response H(f) = X(f)/U(f) of the linearisation at rest. With .step/.mc,
    at every point on one frequency grid (the union of the points' bands); --plot draws
    the family."""
    import springc
    from springc.analyses import ac, family

    for path in (output, plot_path):  # a failed command leaves no output: check both first
        if path:
            check_output_file(path, make_parents=True)
    result = springc.load(netlist).ac(node, input=channel, fmin=fmin, fmax=fmax,
                                      points=points, progress=True)
    if isinstance(result, family.AcFamily):
        family.write_ac_csv(result, output)
        if plot_path:
            family.plot_ac(result, plot_path)
        click.echo(f"wrote {output}: {len(result)} point(s) x {len(result.f_hz)} "
                   f"frequencies, {result.f_hz[0]:g}-{result.f_hz[-1]:g} Hz")
        return
    ac.write_csv(result, output)
    if plot_path:
        ac.plot(result, plot_path)
    peak = int(result.mag.argmax())
    click.echo(f"wrote {output}: {len(result.f_hz)} points, {result.f_hz[0]:g}-"
               f"{result.f_hz[-1]:g} Hz; "
               f"peak |H| {result.mag[peak]:.6g} at {result.f_hz[peak]:.6g} Hz")


@click.command("modes")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--count", type=int, default=None, help="Show only the N slowest modes.")
@click.option("--plot", "plot_path", type=click.Path(), default=None,
              help="Also write a plot (PNG) of the mode frequencies at every point.")
@run_user_errors
def modes_cmd(netlist: str, as_json: bool, count: int | None, plot_path: str | None) -> None:
    """Eigenfrequencies, damping rates, Q factors, dominant nodes and zero modes. With
    .step/.mc, a table per point (JSON: {"file", "points": [{"point": {index, steps, sample,
    seed}, ...}]}); --plot draws each mode's frequency against the point."""
    import springc
    from springc.analyses import family
    from springc.analyses.modes import mode_text

    if plot_path:
        check_output_file(plot_path, make_parents=True)
    report = springc.load(netlist).modes(count)
    if plot_path:
        family.plot_modes(report, plot_path)
    if as_json:
        click.echo(json.dumps(report))
    else:
        click.echo(family.modes_family_text(report) if "points" in report
                   else mode_text(report))

@click.command("noise")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--node", default=None, help="Output node (default: the .noise directive's).")
@click.option("--input", "channel", type=int, default=None,
              help="Input channel k the input-referred noise is referred to (default: "
                   ".noise's, where an F element is driven by it).")
@click.option("--temp", type=float, default=None,
              help="Temperature in kelvin (default: .options temp=, else 300 K).")
@click.option("--fmin", type=float, default=None, help="Lowest frequency, Hz.")
@click.option("--fmax", type=float, default=None, help="Highest frequency, Hz.")
@click.option("--points", type=int, default=None, help="Number of log-spaced frequencies.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="CSV file: f_hz, psd_m2_per_hz, input_referred (if any), one psd:NAME "
                   "column per damper.")
@click.option("--json", "as_json", is_flag=True,
              help='Also print {"f", "psd", "sources", "rms", "input_referred", ...}.')
@plot_option
@run_user_errors
def noise_cmd(netlist, node, channel, temp, fmin, fmax, points, output, as_json,
              plot_path) -> None:
    """Thermal noise at rest: every damper b is a white force of one-sided PSD 4 k_B T b
    (N^2/Hz); the displacement PSD of the node (m^2/Hz), each damper's share, the RMS over
    the band and the input-referred noise, from the linearisation `springc ac` uses."""
    import springc
    from springc.analyses import noise

    for path in (output, plot_path):  # a failed command leaves no output: check both first
        if path:
            check_output_file(path, make_parents=True)
    result = springc.load(netlist).noise(node, input=channel, temp=temp, fmin=fmin,
                                         fmax=fmax, points=points)
    noise.write_csv(result, output)
    if plot_path:
        noise.plot(result, plot_path)
    if as_json:
        click.echo(json.dumps(result.to_json()))
        return
    click.echo(f"wrote {output}: {len(result.f_hz)} points, {result.f_hz[0]:g}-"
               f"{result.f_hz[-1]:g} Hz at {result.temp:g} K; RMS displacement of "
               f"{result.node} over the band {result.rms:.6g} m; "
               f"{len(result.sources)} damper(s)")


COMMANDS = [ac_cmd, modes_cmd, noise_cmd]
