"""What every command shares: error handling and the options used by several commands."""

from __future__ import annotations

import functools
import os
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

import click

from springc.errors import DataError, SpringcError

REPORT_URL = "the springc issue tracker"


DEVICES = click.Choice(["cpu", "cuda", "auto"])  # --device (`springc.sim.gpu.DEVICES`)


def on_device(fn: Callable) -> Callable:
    """Give a command `--device cpu|cuda|auto`: its simulations run there
    (`springc.sim.gpu.default_device`: on the GPU, in this process; `cuda` without a GPU is a
    user error). Goes below `run_user_errors`, which reports that error."""

    @functools.wraps(fn)
    def wrapper(*args, device: str, **kwargs):
        from springc.sim import gpu

        with gpu.default_device(device):
            return fn(*args, **kwargs)

    return click.option(
        "--device", type=DEVICES, default="cpu",
        show_default=True,
        help="Where the mass-spring simulations run: cpu (the CPU kernels; a data set's "
             "batches on Dask workers); cuda (the CUDA kernel form, in this process, a data "
             "set's batch of clips one launch; what it does not run, such as thermal noise "
             "or Strang splitting, stays on the CPU; needs springc[cuda] and an NVIDIA GPU); "
             "auto: cuda where a GPU is present, else cpu.")(wrapper)


def run_user_errors(fn: Callable) -> Callable:
    """Wrap a command: user errors print `file:line:col: error: ...` and exit 1, and so does a
    file the system refuses (`error: PATH: ...`); anything else is an internal error that says
    so, asks for a report and exits 2. Never a bare traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SpringcError as err:
            click.echo(err.format(), err=True)
            sys.exit(1)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except OSError as exc:
            if exc.filename is None:  # no file to name: not the user's input or output
                _internal(exc)
            click.echo(_os_message(exc), err=True)
            sys.exit(1)
        except KeyboardInterrupt:
            click.echo("interrupted", err=True)
            sys.exit(130)
        except Exception as exc:  # noqa: BLE001 - the last line of defence
            _internal(exc)

    return wrapper


def _internal(exc: BaseException) -> None:
    """Report a bug in springc with its traceback and exit 2."""
    click.echo(
        f"INTERNAL ERROR: springc failed unexpectedly ({type(exc).__name__}: {exc}).\n"
        f"This is a bug in springc, not in your input; please report it to "
        f"{REPORT_URL} with the command line and input files.\n"
        + "".join(traceback.format_exception(exc)),
        err=True,
    )
    sys.exit(2)


def _os_message(exc: OSError) -> str:
    """`error: PATH: reason` for a file the system refused to read or write (a folder in
    the way, no permission, disk full): the user's environment, not a bug."""
    where = str(exc.filename)
    if exc.filename2 is not None:
        where += f" -> {exc.filename2}"
    return f"error: {where}: cannot read or write it ({exc.strerror or exc})"


def check_output_file(path: str | Path, make_parents: bool = False) -> None:
    """Fail before any work on an output file that cannot be written: a folder by that name,
    or a parent that is a file or missing (`make_parents`: missing folders will be made, so
    the nearest existing one must be a writable folder)."""
    path = Path(path)
    parent = path.parent
    if path.is_dir():
        raise DataError(str(path), "is a folder; give an output file name")
    if make_parents:
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise DataError(str(path), f"cannot be written: {parent} is a file, not a folder")
    if not parent.exists():
        raise DataError(str(path), f"cannot be written: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DataError(str(path), f"cannot be written: no permission to write in {parent}")


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
        "--plot", "plot_path", type=click.Path(), default=None,
        help="Also write a plot (PNG) of the result.",
    )(fn)
