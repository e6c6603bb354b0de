"""Entry point: the `springc` command group. Each subcommand lives in its own module (see
`commands.TABLE`), is imported only when run, and calls one library function."""

from __future__ import annotations

import click

from springc import __version__
from springc_cli.commands import LazyGroup


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="springc")
def main() -> None:
    """springc: compile, check and simulate springtronic mass-spring netlists (.spr), and
    train and run mass-spring keyword spotters.

    The main job end to end: `springc demo`. Help on one command: `springc COMMAND --help`."""


if __name__ == "__main__":
    main()
