"""The keyword-spotting feature pass (Phi of every clip through the 8x3 mass-spring feature
network, `springc.kws.features.massspring`) on synthetic clips, timed on a device.

    python scripts/kws_feature_pass.py --device cuda --clips 2048 --json kws.json

The clips are speech-like random signals (`springc.bench.suite.speech_like` at the corpus
level, 1 s at 16 kHz: a chirp with pitch-like modulation and noise), not recordings. Phi is
simulated by `massspring.simulate_phi` (its method, substeps and horizon) inside
`gpu.default_device`, as `springc train --device` simulates it, after a compiling call on two
clips. Shorter clips (`--seconds`) are scaled to 1 s ones by the
ratio of their horizons (the steps simulated), and the time for a corpus of `--corpus`
clips (default 20,000) from the clips per second; both printed as scaled.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from springc.bench import suite  # noqa: E402
from springc.kws.features import massspring as msp  # noqa: E402
from springc.sim import gpu  # noqa: E402


def phi(signals, s: msp.MassSpringSettings, device: str, precision: str):
    """Phi (clips, N) by `massspring.simulate_phi`, the feature pass of `springc train`, with
    its simulations on `device` (`gpu.default_device`)."""
    with gpu.default_device(device):
        return msp.simulate_phi(signals, s, precision=precision)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cuda")
    parser.add_argument("--clips", type=int, default=20000, help="clips simulated and timed")
    parser.add_argument("--corpus", type=int, default=20000, help="clips the time is scaled to")
    parser.add_argument("--seconds", type=float, default=1.0, help="clip length")
    parser.add_argument("--precision", default="float64")
    parser.add_argument("--check", type=int, default=0,
                        help="clips whose Phi is compared with the CPU kernels' (0: none)")
    parser.add_argument("--threads", type=int, default=None,
                        help="cuda: threads per run of the split form")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    with gpu.layout(**gpu.env_layout(), **gpu.split_threads(args.threads)):
        return _measure(args)


def _measure(args: argparse.Namespace) -> int:
    """The feature pass timed (`main`'s arguments)."""
    s = msp.MassSpringSettings()
    signals = suite.SPEECH_LEVEL * suite.speech_like(args.seconds, msp.INPUT_RATE, args.clips,
                                                     seed=7)[:, 0, :]
    phi(signals[:2], s, args.device, args.precision)  # compile
    start = time.perf_counter()
    out = phi(signals, s, args.device, args.precision)
    wall = time.perf_counter() - start
    # a 1 s clip's horizon over this clip's: the steps a corpus of 1 s clips would take
    stretch = msp.horizon(s, 1.0) / msp.horizon(s, args.seconds)
    rate = args.clips / (wall * stretch)
    row = {"device": args.device, "precision": args.precision, "clips": args.clips,
           "clip_seconds": args.seconds, "method": s.method, "substeps": s.substeps,
           "features": int(out.shape[1]), "wall_s": wall, "one_second_stretch": stretch,
           "one_second_clips_per_s": rate,
           "corpus": args.corpus, "corpus_s_scaled": args.corpus / rate,
           "finite": bool(abs(out).max() < float("inf"))}
    print(f"feature pass ({args.device}, {args.precision}, {s.method} x{s.substeps}): "
          f"{args.clips} clips of {args.seconds} s in {wall:.2f} s; scaled to 1 s clips "
          f"(x{stretch:.2f} steps) {rate:,.1f} clips/s, a {args.corpus}-clip corpus "
          f"{args.corpus / rate:.1f} s", flush=True)
    if args.check:
        _check_against_cpu(args, signals, s, out, row)
    if args.json:
        Path(args.json).write_text(json.dumps(row, indent=1))
    return 0


def _check_against_cpu(args: argparse.Namespace, signals, s: msp.MassSpringSettings, out,
                       row: dict) -> None:
    """The first `--check` clips' Phi against the CPU kernels': the largest difference over
    the largest |Phi|, into `row` and printed."""
    want = phi(signals[:args.check], s, "cpu", args.precision)
    row["phi_difference_vs_cpu"] = float(abs(out[:args.check] - want).max()
                                          / abs(want).max())
    print(f"Phi of {args.check} clips within {row['phi_difference_vs_cpu']:.2e} of the "
          "CPU kernels' (max difference over max |Phi|)", flush=True)


if __name__ == "__main__":
    sys.exit(main())
