"""Entry point: the `springc` command group. Each subcommand lives in its own module and calls
one library function."""

from __future__ import annotations

import click

from springc import __version__


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="springc")
def main() -> None:
    """springc: compile, check and simulate springtronic mass-spring netlists (.spr)."""


def _register() -> None:
    """Attach the subcommands (imported here so `springc --help` lists them all)."""
    from springc_cli import commands

    for command in commands.ALL:
        main.add_command(command)


_register()


if __name__ == "__main__":
    main()
