"""The command group: every command in the lazy table loads, and its one-line help matches."""

from __future__ import annotations

import subprocess

import pytest
from click.testing import CliRunner

from springc_cli.commands import TABLE, load
from springc_cli.main import main


@pytest.mark.parametrize("name", sorted(TABLE))
def test_command_loads_under_its_name(name):
    command = load(name)
    assert command.name == name


def test_help_lists_every_command():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0
    for name, (_, _, short) in TABLE.items():
        assert name in result.output and short in result.output


def test_unknown_command_exits_2_without_traceback():
    result = CliRunner().invoke(main, ["frobnicate"])
    assert result.exit_code == 2 and "Traceback" not in result.output


def test_installed_entry_point_runs():
    out = subprocess.run(["springc", "--version"], capture_output=True, text=True, check=True)
    assert "springc" in out.stdout
