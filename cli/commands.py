"""The list of subcommands; each module defines one or more click commands."""

from __future__ import annotations

ALL: list = []

from springc_cli import design  # noqa: E402  (springc design ...)

ALL += design.COMMANDS

from springc_cli import figures  # noqa: E402  (springc figures OUTDIR)

ALL += figures.COMMANDS

from springc_cli import kws  # noqa: E402  (springc train, springc eval)

ALL += [kws.train_cmd, kws.eval_cmd]

from springc_cli import export  # noqa: E402  (springc export --spice)

ALL += [export.export_cmd]

from springc_cli import sim  # noqa: E402  (springc sim)

ALL += [sim.sim_cmd]

from springc_cli import export  # noqa: E402  (springc export --spice)

ALL += [export.export_cmd]

from springc_cli import data  # noqa: E402  (springc data synth, springc data info)

ALL += data.COMMANDS

from springc_cli import build  # noqa: E402  (springc build)

ALL += build.COMMANDS

from springc_cli import analyses  # noqa: E402  (springc ac, springc modes)

ALL += analyses.COMMANDS

from springc_cli import bench  # noqa: E402  (springc bench)

ALL += [bench.bench_cmd]

from springc_cli import demo  # noqa: E402  (springc demo)

ALL += demo.COMMANDS
