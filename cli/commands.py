"""Where each subcommand lives, so `springc` imports only the one it runs.

Importing every command module up front costs seconds (numba, scikit-learn, matplotlib); the
table below names each command's module and object and carries its one-line help for
`springc --help`. A test checks that every entry loads a command of its name.
"""

from __future__ import annotations

import importlib

import click

# name -> (module in springc_cli, attribute, short help)
TABLE: dict[str, tuple[str, str, str]] = {
    "build": ("build", "build_cmd", "Parse, elaborate and check a netlist; print its summary."),
    "sim": ("sim", "sim_cmd", "Simulate a netlist for every input signal; write the probes."),
    "grad": ("grad", "grad_cmd", "Gradient of a reduction with respect to .param values."),
    "ac": ("analyses", "ac_cmd", "Frequency response of the linearisation at rest."),
    "modes": ("analyses", "modes_cmd", "Eigenfrequencies, damping, Q and mode shapes."),
    "noise": ("analyses", "noise_cmd", "Thermal-noise PSD of a node at rest (.noise)."),
    "design": ("design", "design", "Design building blocks (Mel filterbank, MVM, ...)."),
    "figures": ("figures", "figures_cmd", "Building-block experiments as PNG figures."),
    "export": ("export", "export_cmd", "Export a netlist to ngspice (force-current analogy)."),
    "data": ("data", "data_group", "Speech data: synthesise the built-in corpus, inspect one."),
    "train": ("kws", "train_cmd", "Train a keyword spotter; write a model folder."),
    "eval": ("kws", "eval_cmd", "Evaluate a model on the test split."),
    "classify": ("kws", "classify_cmd", "What a model hears in recordings; --stream: when."),
    "tune": ("tune", "tune_cmd", "Tune a mass-spring keyword spotter through its network."),
    "cv": ("kws", "cv_cmd", "Cross-validate digital against mass-spring on every clip."),
    "demo": ("demo", "demo_cmd", "The main job end to end on the built-in corpus."),
    "bench": ("bench", "bench_cmd", "Speed against error: integrators and peers side by side."),
}


def load(name: str) -> click.Command:
    """Import and return the command called `name`."""
    module, attr, _ = TABLE[name]
    return getattr(importlib.import_module(f"springc_cli.{module}"), attr)


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(TABLE)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return load(cmd_name) if cmd_name in TABLE else None

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, TABLE[name][2]) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)
