"""The list of subcommands; each module defines one or more click commands."""

from __future__ import annotations

ALL: list = []
