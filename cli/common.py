"""What every command shares: error handling and the options used by several commands."""

from __future__ import annotations

import functools
import sys
import traceback
from collections.abc import Callable

import click

from springc.errors import SpringcError

REPORT_URL = "the springc issue tracker"


def run_user_errors(fn: Callable) -> Callable:
    """Wrap a command: user errors print `file:line:col: error: ...` and exit 1; anything else
    is an internal error that says so, asks for a report and exits 2. Never a bare traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SpringcError as err:
            click.echo(err.format(), err=True)
            sys.exit(1)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except KeyboardInterrupt:
            click.echo("interrupted", err=True)
            sys.exit(130)
        except Exception as exc:  # noqa: BLE001 - the last line of defence
            click.echo(
                f"INTERNAL ERROR: springc failed unexpectedly ({type(exc).__name__}: {exc}).\n"
                f"This is a bug in springc, not in your input; please report it to "
                f"{REPORT_URL} with the command line and input files.\n"
                + "".join(traceback.format_exception(exc)),
                err=True,
            )
            sys.exit(2)

    return wrapper


def precision_option(fn: Callable) -> Callable:
    """--precision float64|float32."""
    return click.option(
        "--precision",
        type=click.Choice(["float64", "float32"]),
        default=None,
        help="Floating-point precision of the simulation (default: netlist option or float64).",
    )(fn)


def plot_option(fn: Callable) -> Callable:
    """--plot FILE.png."""
    return click.option(
        "--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
        help="Also write a plot (PNG) of the result.",
    )(fn)
