"""The GPU page's figure: runs per second of the 8x3 feature network on one GPU, the CUDA
split form by threads per run with each node's terms read in loops or held in registers,
beside JAX and diffrax on the same GPU (equal error), from `gpu_check.sh`'s JSON.

    python scripts/gpu_figure.py docs/bench/gpu/2026-11-27-h200 docs/bench/gpu-h200-features.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def bars(folder: Path) -> list[tuple[str, float, str]]:
    """(label, runs per second, colour) of each bar."""
    rows = json.loads((folder / "split_threads.json").read_text())["rows"]
    out = []
    for slot, name, colour in ((0, "loops", "#9aa5b1"), (8, "registers", "#1f6fb4")):
        for r in rows:
            if r.get("slot_max") == slot and "runs_per_s" in r:
                out.append((f"springc\n{r['threads_per_run']} thr.\n{name}", r["runs_per_s"],
                            colour))
    peers = json.loads((folder / "peers_features.json").read_text())
    out += [("JAX", peers["jax"]["runs_per_s"], "#d08c2f"),
            ("diffrax", peers["diffrax"]["runs_per_s"], "#b5651d")]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--gpu", default="NVIDIA H200")
    args = parser.parse_args(argv)
    data = bars(args.folder)
    fig, ax = plt.subplots(figsize=(7.5, 3.4), dpi=100)
    ax.bar(range(len(data)), [v for _, v, _ in data], color=[c for _, _, c in data])
    for k, (_, v, _) in enumerate(data):
        ax.text(k, v, f"{v:,.0f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(data)), [lab for lab, _, _ in data], fontsize=7)
    ax.set_ylabel("runs of 0.02 s per second")
    ax.set_title(f"8x3 feature network (488 dofs), RK4 x8, float64, 10,000 runs, {args.gpu}",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
