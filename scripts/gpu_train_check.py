"""`springc train` and `springc eval` of a mass-spring keyword spotter with the simulations on
a device, against the same on the CPU: the whole path of `--device cuda` (the feature pass in
this process, a batch of clips a launch; the classifier network per test clip), on a small
synthetic corpus (tones and noise bursts, not speech) written here.

    python scripts/gpu_train_check.py --device cuda --json train.json

Trains a 4x2 model with the paper's integration (RK4 x8, float32) on each device, then
evaluates each with the whole classifier network simulated on that device; prints the wall
times, both accuracies and the largest difference between the two models' weights (max
difference over max magnitude, over the numeric arrays of `weights.npz`).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import soundfile as sf

from springc.kws.evaluation.evaluate import evaluate
from springc.kws.features.digital import FeatureSettings
from springc.kws.training.train import TrainOptions, train
from springc.sim import gpu

RATE = 16000
WORDS = ("yes", "no", "up")
SPEAKERS = [f"{i:08x}" for i in range(0x5a000000, 0x5a000008)]  # 6 train, 1 val, 1 test


def word(k: int, rng: np.random.Generator) -> np.ndarray:
    """A 1 s clip: word k's tone (rising with k) under a window, and noise."""
    t = np.arange(RATE) / RATE
    start = rng.uniform(0.1, 0.4)
    env = np.exp(-((t - start - 0.2) / 0.12) ** 2)
    f = 300.0 * (k + 1) * (1 + 0.1 * rng.normal())
    return 0.3 * env * np.sin(2 * np.pi * f * t) + 0.003 * rng.normal(size=RATE)


def corpus(root: Path, per_speaker: int = 3) -> Path:
    """A GSCD-layout folder of WORDS, SPEAKERS x per_speaker clips each, with split lists."""
    rng = np.random.default_rng(0)
    val, test = [], []
    for k, w in enumerate(WORDS):
        (root / w).mkdir(parents=True)
        for s, spk in enumerate(SPEAKERS):
            for j in range(per_speaker):
                name = f"{w}/{spk}_nohash_{j}.wav"
                sf.write(root / name, word(k, rng), RATE, subtype="PCM_16")
                (val if s == 6 else test if s == 7 else []).append(name)
    (root / "validation_list.txt").write_text("\n".join(val) + "\n")
    (root / "testing_list.txt").write_text("\n".join(test) + "\n")
    return root


def run(device: str, data: Path, out: Path) -> dict:
    """Train and evaluate on `device`: times, accuracy, the model's Phi and decisions."""
    with gpu.default_device(device):
        start = time.perf_counter()
        train(TrainOptions(data=data, out=out, settings=FeatureSettings(bins=4, delays=2),
                           realisation="mass-spring", jobs=2, use_cache=False, tolerance=None))
        mid = time.perf_counter()
        report = evaluate(out, data, use_cache=False, jobs=2)
        end = time.perf_counter()
    phi = np.load(out / "weights.npz")
    return {"device": device, "train_s": mid - start, "eval_s": end - mid,
            "accuracy": report["accuracy"], "n": report["n"],
            "weights": {k: phi[k] for k in phi.files}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        data = corpus(Path(tmp) / "data")
        rows = [run(d, data, Path(tmp) / f"model-{d}") for d in (args.device, "cpu")]
    numeric = [k for k, v in rows[1]["weights"].items() if v.dtype.kind == "f"]
    diff = max(float(np.abs(rows[0]["weights"][k] - rows[1]["weights"][k]).max()
                     / (np.abs(rows[1]["weights"][k]).max() or 1.0)) for k in numeric)
    for r in rows:
        print(f"{r['device']}: train {r['train_s']:.1f} s, eval {r['eval_s']:.1f} s, "
              f"accuracy {r['accuracy']:.3f} on {r['n']} clips", flush=True)
    print(f"the models' weights differ by {diff:.2e} (max difference over max magnitude)")
    if args.json:
        keep = [{k: v for k, v in r.items() if k != "weights"} for r in rows]
        Path(args.json).write_text(json.dumps({"runs": keep, "weights_difference": diff},
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
