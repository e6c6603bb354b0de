"""`springc figures OUTDIR`: the building-block figures of the paper's Sec. III as PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import click
from springc_cli.common import run_user_errors

from springc.design import figures
from springc.design.emit import write_atomic
from springc.errors import UsageError


@click.command("figures")
@click.argument("outdir", type=click.Path())
@click.option("--only", multiple=True, type=click.Choice(figures.FIGURES),
              help="Make only these figures (repeatable); default all.")
@run_user_errors
def figures_cmd(outdir: str, only: tuple[str, ...]) -> None:
    """Run the building-block experiments and write OUTDIR/<name>.png for: melbank (paper
    Fig. 4), dispersion (Fig. 3d), pulse (delay per site), mvm (zero modes and x_out = Q x_in),
    energetics (Fig. 5b), readout (Fig. 6b), squaring (Fig. 6c-d: energy transfer and
    distortion of one quadratic coupling against eps), features (Fig. 7: filter, squarer,
    low-pass and delayed copies); the measured numbers go to OUTDIR/figures.json."""
    from tqdm import tqdm

    if Path(outdir).exists() and not Path(outdir).is_dir():
        raise UsageError(f"{outdir} is a file; OUTDIR must be a folder (it is created if "
                         f"missing)")
    numbers: dict[str, dict[str, float]] = {}
    for name in tqdm(only or figures.FIGURES, unit="figure", desc="figures"):
        numbers.update(figures.write_figures(outdir, (name,)))
    old = _existing(f"{outdir}/figures.json")
    old.update(numbers)
    write_atomic(f"{outdir}/figures.json", json.dumps(old, indent=2) + "\n")
    for name, values in numbers.items():
        shown = ", ".join(f"{k} = {v:.6g}" for k, v in values.items())
        click.echo(f"{outdir}/{name}.png: {shown}")


def _existing(path: str) -> dict:
    """Numbers of an earlier run (kept for the figures not redone with --only)."""
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return {}


COMMANDS = [figures_cmd]
