"""`springc bench`: the kernel's throughput and accuracy against numpy and scipy peers."""

from __future__ import annotations

import click

from springc_cli.common import run_user_errors


@click.command("bench")
@click.option("--seconds", type=float, default=1.0, show_default=True,
              help="Simulated seconds of noise input per kernel run.")
@click.option("--batch", type=int, default=64, show_default=True,
              help="Runs simulated together in the batched measurement.")
@click.option("--stretch", type=float, default=0.02, show_default=True,
              help="Simulated seconds for the slow peers (numpy, scipy); scaled per second.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              default="bench-out/bench.json", show_default=True, help="Where to write JSON.")
@run_user_errors
def bench_cmd(seconds, batch, stretch, json_path):
    """Benchmark the generated kernel on the 564-dof keyword-spotting-sized network: float64
    and float32 at batch 1 and 64, compile time cold and cached, and plain numpy RK4 and scipy
    RK45/DOP853 (rtol 1e-6), each with its error against a tight reference. Prints a Markdown
    table."""
    from springc.bench import markdown, run_bench, write_json

    result = run_bench(seconds, batch, stretch, progress=lambda m: click.echo(m, err=True))
    write_json(result, json_path)
    click.echo(markdown(result))
    click.echo(f"\n(JSON: {json_path})")
