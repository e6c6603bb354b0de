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
              help='Print {"of": SPEC, "value": v, "grad": {PARAM: dv/dPARAM}} (with .step '
                   'or --per-run, a list of them, with "point" and "run" keys).')
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
    are summed over the runs unless --per-run.

    With .step/.mc, at every point (its step values set, its draws drawn): one row per point
    (JSON: a list of rows, each with a "point" key: index, step values, sample, seed). At a
    Monte Carlo sample each draw's unit deviate is held fixed: d gauss(nom, rvar) / d nom is
    the draw over nom, the derivative of that fabricated device."""
    import springc

    net = springc.load(netlist, method=method, tstep=tstep, substeps=substeps)
    net.variation  # a misused .step/.mc is the first error
    net.source.require(list(params))
    res = net.grad(spec, list(params), list(inputs) or None, tstep=tstep, tstop=tstop,
                   substeps=substeps, method=method, channel=channel)
    if res.points is None:
        rows = _rows(res.values[spec], res.grad, res.wrt, res.runs, spec, per_run)
    else:
        rows = [{"point": p.to_json(), **row} for i, p in enumerate(res.points)
                for row in _rows(res.values[spec][i], res.grad[i], res.wrt, res.runs, spec,
                                 per_run)]
    if as_json:
        click.echo(json.dumps(rows if per_run or res.points is not None else rows[0]))
        return
    for row in rows:
        click.echo(_text(row))


def _rows(value, grad, wrt: list[str], runs: list[str], spec: str,
          per_run: bool) -> list[dict]:
    """JSON-ready rows of one point: one per run, or one summed over the runs."""
    if not per_run:
        total = value.sum(axis=0)
        return [{"of": spec, "value": total.tolist(),
                 "grad": dict(zip(wrt, grad.sum(axis=0).tolist()))}]
    return [{"run": run, "of": spec, "value": value[r].tolist(),
             "grad": dict(zip(wrt, grad[r].tolist()))}
            for r, run in enumerate(runs)]


def _text(row: dict) -> str:
    head = f"{row['run']}: " if "run" in row else ""
    if "point" in row:
        point = row["point"]
        parts = [f"{k}={v:g}" for k, v in point["steps"].items()]
        if point["sample"] is not None:
            parts += [f"sample {point['sample']}", f"seed {point['seed']}"]
        head = f"point {point['index']} ({', '.join(parts)}) {head}"
    value = row["value"]
    shown = f"{value:.10g}" if isinstance(value, float) else str(value)
    lines = [f"{head}{row['of']} = {shown}"]
    width = max(len(p) for p in row["grad"])
    lines += [f"  d/d{p:<{width}} {g: .10g}" for p, g in row["grad"].items()]
    return "\n".join(lines)


COMMANDS = [grad_cmd]
