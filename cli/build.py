"""`springc build`: check a netlist and print its summary (or one JSON object)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import click
from springc_cli.common import run_user_errors


@click.command("build")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--emit-kernel", type=click.Path(dir_okay=False), default=None,
              help="Also write the generated kernel source to this file.")
@click.option("--method", default=None,
              help="Integrator (overrides .options method=): rk4, rk38, ssprk3, heun3, midpoint.")
@run_user_errors
def build_cmd(netlist: str, as_json: bool, emit_kernel: str | None, method: str | None) -> None:
    """Parse, elaborate and check NETLIST; print dofs, elements, fastest mode and dt_max."""
    from springc import compiler

    report = compiler.build(netlist, method=method)
    if emit_kernel:
        _write(Path(emit_kernel), compiler.kernel_source(report))
    click.echo(json.dumps(report.to_json()) if as_json else report.summary())


def _write(path: Path, text: str) -> None:
    """Atomically: a temp file beside `path`, then rename."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


COMMANDS = [build_cmd]
