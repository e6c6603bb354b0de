"""`springc build`: check a netlist and print its summary (or one JSON object)."""

from __future__ import annotations

import json
from pathlib import Path

import click
from springc_cli.common import check_output_file, run_user_errors

from springc.design.emit import write_atomic
from springc.errors import NetlistError
from springc.lang.options import known_methods


@click.command("build")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--emit-kernel", type=click.Path(), default=None,
              help="Also write the generated kernel source to this file.")
@click.option("--method", default=None,
              help="Integrator (overrides .options method=): "
                   f"{', '.join(known_methods())}. The split schemes (strang-rk4, exp-rk4, "
                   "exp-heun3) integrate the driven linear filter blocks exactly: only the rest "
                   "limits the step.")
@click.option("--tolerance", type=float, default=None,
              help="Report the integration springc sim chooses for this error target (the "
                   "default 1e-3 where neither --method nor the netlist's .options pin it).")
@run_user_errors
def build_cmd(netlist: str, as_json: bool, emit_kernel: str | None, method: str | None,
              tolerance: float | None) -> None:
    """Parse, elaborate and check NETLIST; print dofs, elements, fastest mode, dt_max and the
    integration `springc sim` takes (pinned by the netlist or --method, else chosen)."""
    from springc.check import compiler

    if emit_kernel:
        check_output_file(emit_kernel, make_parents=True)
    report = compiler.build(netlist, method=method, tolerance=tolerance)
    if emit_kernel and isinstance(report, compiler.LibraryReport):
        raise NetlistError(f"{netlist}: a library of subcircuits has no kernel",
                           hint="instantiate a subcircuit in a netlist and build that")
    if emit_kernel:
        write_atomic(Path(emit_kernel), compiler.kernel_source(report))
    click.echo(json.dumps(report.to_json()) if as_json else report.summary())


COMMANDS = [build_cmd]
