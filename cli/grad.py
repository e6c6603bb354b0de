"""`springc grad`: the gradient of a streaming reduction with respect to `.param` values."""

from __future__ import annotations

import json

import click
from springc_cli.common import run_user_errors

from springc.kernels.integrators import TABLEAUX


@click.command("grad")
@click.argument("netlist", type=click.Path(dir_okay=False))
@click.option("--of", "spec", required=True, metavar="SPEC",
              help="The reduction, as springc sim --reduce takes it: final:x(N), "
                   "msq:x(N)[:T0:T1], work:in, work:FNAME, dissipated:NAME, loss:NAME, "
                   "gram:TAU:N1,N2 (a Gram reduction: the gradient of the sum of its entries).")
@click.option("--wrt", "params", required=True, multiple=True, metavar="PARAM",
              help="A top-level .param of the netlist (repeatable).")
@click.option("--input", "-i", "inputs", multiple=True, metavar="FILE-OR-DIR",
              help="Sound file for in(k), or a folder of them; each file is one run.")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"of": SPEC, "value": v, "grad": {PARAM: dv/dPARAM}}.')
@click.option("--per-run", is_flag=True,
              help="One row per input (JSON: a list of such objects with a \"run\" key) "
                   "instead of the sum over runs.")
@click.option("--tstep", type=float, help="Input grid step in seconds (overrides .tran).")
@click.option("--tstop", type=float, help="Stop time in seconds (overrides .tran).")
@click.option("--substeps", type=int, help="Integration steps per input sample (default 1).")
@click.option("--method", type=click.Choice(list(TABLEAUX)), default=None,
              help="Runge-Kutta integrator (default: netlist option or rk4).")
@click.option("--channel", type=int, default=None,
              help="File channel feeding in(0) (needed for stereo files).")
@run_user_errors
def grad_cmd(netlist, spec, params, inputs, as_json, per_run, tstep, tstop, substeps, method,
             channel):
    """d SPEC / d PARAM for NETLIST, exact for the simulated (float64) computation: the
    discrete adjoint of the integrator's step. With several inputs, the value and gradient
    are summed over the runs unless --per-run."""
    from springc.grad import ParamNetlist, gradient

    pn = ParamNetlist.load(netlist)
    pn.require(list(params))
    res = gradient(pn, spec, list(params), list(inputs) or None, tstep=tstep, tstop=tstop,
                   substeps=substeps, method=method, channel=channel)
    rows = _rows(res, spec, per_run)
    if as_json:
        click.echo(json.dumps(rows if per_run else rows[0]))
        return
    for row in rows:
        click.echo(_text(row))


def _rows(res, spec: str, per_run: bool) -> list[dict]:
    """JSON-ready rows: one per run, or one summed over the runs."""
    value = res.values[spec]
    if not per_run:
        total = value.sum(axis=0)
        return [{"of": spec, "value": total.tolist(),
                 "grad": dict(zip(res.wrt, res.grad.sum(axis=0).tolist()))}]
    return [{"run": run, "of": spec, "value": value[r].tolist(),
             "grad": dict(zip(res.wrt, res.grad[r].tolist()))}
            for r, run in enumerate(res.runs)]


def _text(row: dict) -> str:
    head = f"{row['run']}: " if "run" in row else ""
    value = row["value"]
    shown = f"{value:.10g}" if isinstance(value, float) else str(value)
    lines = [f"{head}{row['of']} = {shown}"]
    width = max(len(p) for p in row["grad"])
    lines += [f"  d/d{p:<{width}} {g: .10g}" for p, g in row["grad"].items()]
    return "\n".join(lines)


COMMANDS = [grad_cmd]
