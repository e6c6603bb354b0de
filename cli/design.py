"""`springc design ...`: compute building-block parameters and write readable `.spr` files."""

from __future__ import annotations

import click
import numpy as np
from springc_cli.common import check_output_file, plot_option, run_user_errors

from springc.design import blocks, melbank, mvm
from springc.design.emit import params_text, write_atomic
from springc.design.filters import DEFAULT_FMAX, DEFAULT_FMIN

OUT = click.option("-o", "--output", "output", type=click.Path(), required=True,
                   help="The .spr file to write.")


@click.group("design")
def design() -> None:
    """Design building blocks (Mel filterbank, MVM, delay line, readout, low-pass) and write
    them as .spr files."""


@design.command("melbank")
@click.option("--bins", type=click.IntRange(1, 512), required=True, help="Number of Mel bins.")
@click.option("--fmin", type=float, default=DEFAULT_FMIN, show_default=True, help="Hz.")
@click.option("--fmax", type=float, default=DEFAULT_FMAX, show_default=True, help="Hz.")
@click.option("--kind", type=click.Choice(melbank.KINDS), default="two-mode", show_default=True,
              help="Filter written to the file (both are fitted and reported).")
@click.option("--name", default="melbank", show_default=True, help="Subcircuit name.")
@OUT
@plot_option
@run_user_errors
def melbank_cmd(bins: int, fmin: float, fmax: float, kind: str, name: str, output: str,
                plot_path: str | None) -> None:
    """Fit BINS mechanical filters to triangular Mel filters and write `.subckt NAME out0 ..
    out{BINS-1} ch=0`; prints the misfit per bin for the two-mode and single-mode fits."""
    check_output_file(output)
    if plot_path:
        check_output_file(plot_path)
    bank = melbank.design_melbank(bins, fmin, fmax)
    melbank.write_melbank(bank, output, kind=kind, name=name)
    click.echo(melbank.misfit_table(bank))
    click.echo(f"wrote {output} ({kind} filters, subcircuit {name})")
    if plot_path:
        from springc.design import figures

        figures.plot_melbank(bank, plot_path)
        click.echo(f"wrote {plot_path}")


@design.command("mvm")
@click.option("--matrix", type=click.Path(dir_okay=False), required=True,
              help="Orthogonal N x N matrix Q (.npy).")
@click.option("--mass", "m", type=float, default=1e-3, show_default=True,
              help="Mass of the delay-line sites it is matched to (kg); the block uses half.")
@click.option("--kc", type=float, default=10.0, show_default=True,
              help="Coupling of the delay lines it is matched to (N/m).")
@click.option("--damping", "b", type=float, default=None,
              help="Matched damping of the delay lines (N s/m; default sqrt(mass kc)); the "
                   "block uses half.")
@click.option("--stiffness", type=float, default=None,
              help="Stiffness d of the non-zero modes (N/m; default 1000 kc).")
@OUT
@run_user_errors
def mvm_cmd(matrix: str, m: float, kc: float, b: float | None, stiffness: float | None,
            output: str) -> None:
    """Write `.subckt mvm in0 .. out{N-1}`: a matrix-vector multiplier whose zero modes are
    exactly [I; Q] (zero-mode engineering)."""
    check_output_file(output)
    q = mvm.load_matrix(matrix)
    d = mvm.design_mvm(q, m=m, b=b, kc=kc, stiffness=stiffness)
    mvm.write_mvm(d, output, source=matrix)
    click.echo(f"N = {d.n}: {len(d.couplings)} couplings, stiffness d = {d.stiffness:g} N/m, "
               f"stiff modes at {d.stiff_mode_hz():.4g} Hz (delay-line band edge "
               f"{d.band_edge_hz():.4g} Hz)")
    err = float(np.max(np.abs(d.assembled_stiffness() - d.K)) / d.stiffness)
    click.echo(f"elements reproduce K = d [[I, -Q^T], [-Q, I]] to {err:.2g} relative")
    click.echo(f"wrote {output}")


@design.command("summer")
@click.option("--weights", required=True, metavar="W0,W1,...",
              help="The weights (comma-separated, not all zero; a zero adds no spring).")
@click.option("--kappa", type=float, default=1.0, show_default=True,
              help="Coupling stiffness per unit weight (N/m): how hard the sum loads its "
                   "inputs.")
@click.option("--resonance", type=float, default=500.0, show_default=True,
              help="The output's resonance (Hz): keep it well above the inputs' band.")
@click.option("--zeta", type=float, default=0.7, show_default=True,
              help="The output's damping ratio.")
@click.option("--name", default="summer", show_default=True, help="Subcircuit name.")
@OUT
@run_user_errors
def summer_cmd(weights: str, kappa: float, resonance: float, zeta: float, name: str,
               output: str) -> None:
    """A weighted sum by springs, out = sum w_p in_p / sum |w| (no zero modes, no cancelling
    stiffness: robust to fabrication spread); writes `.subckt NAME in0 .. in{N-1} out`."""
    from springc.design.summer import design_summer, write_summer
    from springc.errors import UsageError

    check_output_file(output)
    try:
        values = [float(v) for v in weights.split(",")]
    except ValueError:
        raise UsageError(f"--weights: {weights!r} is not a comma-separated list of numbers")
    design_ = design_summer(values, kappa, resonance, zeta)
    write_summer(design_, output, name)
    click.echo(f"gains {' '.join(f'{g:.6g}' for g in design_.gains)}; output held by "
               f"{design_.stiffness:.6g} N/m, mass {design_.m:.6g} kg")
    click.echo(f"wrote {output} (subcircuit {name})")


@design.command("delayline")
@click.option("--td", type=float, required=True, help="Delay per site (s).")
@click.option("--kc", type=float, default=10.0, show_default=True, help="Coupling (N/m).")
@click.option("--prefix", default="dl", show_default=True, help="Prefix of the .param names.")
@OUT
@run_user_errors
def delayline_cmd(td: float, kc: float, prefix: str, output: str) -> None:
    """Delay-line parameters for delay TD per site: m = td^2 kc, kl = 1e-6 kc, matched
    damping sqrt(m kc); written as `.param` lines."""
    check_output_file(output)
    p = blocks.delayline_params(td, kc)
    values = {"m": p.m, "kc": p.kc, "kl": p.kl, "b": p.b_match, "td": p.td}
    text = params_text(
        prefix, values,
        f"delay line: {td:g} s per site with kc = {kc:g} N/m (paper Eq. dispersion_rel)",
        f"Xd in out delayline n=<sites> td={{{prefix}_td}} kc={{{prefix}_kc}} term=1")
    _write_params(output, text, values, prefix)


@design.command("readout")
@click.option("--tau", type=float, required=True, help="Integration time constant (s).")
@click.option("--qr", type=float, default=blocks.READOUT_Q, show_default=True,
              help="Quality factor (< 0.5).")
@click.option("--mass", "m", type=float, default=1.0, show_default=True, help="kg.")
@click.option("--kext", type=float, default=0.0, show_default=True,
              help="Stiffness supplied from outside, e.g. the sum of g a of the quadratic "
                   "couplings (N/m).")
@click.option("--prefix", default="ro", show_default=True, help="Prefix of the .param names.")
@OUT
@run_user_errors
def readout_cmd(tau: float, qr: float, m: float, kext: float, prefix: str, output: str) -> None:
    """Leaky-integrator readout with time constant TAU: tau = 2Q / (w (1 - sqrt(1 - 4Q^2)));
    written as `.param` lines."""
    check_output_file(output)
    p = blocks.readout_params(tau, qr, m, kext)
    values = {"m": p.m, "k": p.k_local, "ktotal": p.k_total, "b": p.b, "omega": p.omega,
              "tau": p.tau}
    text = params_text(
        prefix, values, f"readout: tau = {tau:g} s, Q = {qr:g}, m = {m:g} kg, external "
        f"stiffness {kext:g} N/m (paper Sec. III.B)",
        f"Xr r readout tau={{{prefix}_tau}} qr={qr:g} m={{{prefix}_m}} kext={kext:g}")
    _write_params(output, text, values, prefix)


@design.command("lowpass")
@click.option("--fc", type=float, required=True, help="Cutoff frequency (Hz).")
@click.option("--k", "k", type=float, default=1.0, show_default=True, help="Stiffness (N/m).")
@click.option("--bext", type=float, default=0.0, show_default=True,
              help="Damping supplied by attached delay lines (N s/m).")
@click.option("--prefix", default="lp", show_default=True, help="Prefix of the .param names.")
@OUT
@run_user_errors
def lowpass_cmd(fc: float, k: float, bext: float, prefix: str, output: str) -> None:
    """Critically damped low-pass with cutoff FC: m = k / (2 pi fc)^2, b = 2 k / (2 pi fc);
    written as `.param` lines."""
    check_output_file(output)
    p = blocks.lowpass_params(fc, k, bext)
    values = {"m": p.m, "k": p.k, "b": p.b, "btotal": p.b_total, "fc": p.fc}
    text = params_text(
        prefix, values, f"low-pass: fc = {fc:g} Hz, k = {k:g} N/m, critically damped",
        f"Xlp node lowpass fc={{{prefix}_fc}} k={{{prefix}_k}} bext={bext:g}")
    _write_params(output, text, values, prefix)


@design.command("scale")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--mass", type=float, required=True,
              help="kg per normalised mass unit (every mass, damping and stiffness x this).")
@click.option("--length", type=float, required=True,
              help="m per normalised displacement unit.")
@click.option("--spl", type=float, default=None,
              help="With --area: the in(k) forces become sound pressure at this level (dB "
                   "SPL, re 20 uPa) on a membrane: a unit-RMS input is a force p A.")
@click.option("--area", type=float, default=None, help="Membrane area (m^2), with --spl.")
@OUT
@run_user_errors
def scale_cmd(netlist: str, mass: float, length: float, spl: float | None,
              area: float | None, output: str) -> None:
    """Rewrite NETLIST, designed in normalised units (unit masses, unit displacements), as
    the same dynamics at a physical scale: every coefficient and source gain multiplied by
    the factor of its degree (docs/language.md#physical-units); written as a flat .spr."""
    import springc
    from springc.design.scale import acoustic_gains, flat_text, scale_netlist
    from springc.errors import UsageError

    check_output_file(output, make_parents=True)
    if (spl is None) != (area is None):
        raise UsageError("--spl and --area go together (the acoustic force is p A)")
    net = scale_netlist(springc.load(netlist).flat, mass, length)
    if spl is not None:
        net = acoustic_gains(net, spl, area)
    note = (f"{netlist} at mass scale {mass:g} kg and length scale {length:g} m "
            "(springc design scale)" + (f"; input: {spl:g} dB SPL on {area:g} m^2"
                                       if spl is not None else ""))
    text = flat_text(net, note)
    springc.load(text)  # what is written must load and pass the checks
    write_atomic(output, text)
    click.echo(f"wrote {output}: {net.n} masses, mass x {mass:g}, length x {length:g}")


def _write_params(output: str, text: str, values: dict[str, float], prefix: str) -> None:
    write_atomic(output, text)
    for key, value in values.items():
        click.echo(f"{prefix}_{key} = {value:.10g}")
    click.echo(f"wrote {output}")


COMMANDS = [design]
