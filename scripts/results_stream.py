"""Keyword spotting over long recordings (`springc classify --stream`), measured: recordings
made of a data set's test clips (commands and other words, as recorded, not centred) between
gaps of its held-out background noise, streamed by each model; a command is found when a
detection of its label lies within TOLERANCE s of its energy centre. Prints a Markdown table
beside each model's accuracy on the same command clips classified one by one.

    python scripts/results_stream.py --data CORPUS --model MODEL [--model MODEL ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import soundfile as sf

from springc.kws.evaluation.classify import classify
from springc.kws.data.dataset import (COMMANDS, NOISE_REGIONS, SAMPLE_RATE, fit_length,
                                      read_converted)
from springc.kws.data.preprocess import energy_centroid, remove_background
from springc.kws.evaluation.stream import stream
from springc.kws.data.task import open_task_data

TOLERANCE = 0.3  # s between a detection and the word's energy centre
NOISE_GAIN = 0.03  # background level (training augmentation: uniform gain up to 0.1)


def recording(clips: list, noise: np.ndarray, rng: np.random.Generator) -> tuple:
    """(signal, [(label, centre time)]): the clips between gaps of 0.4-1.0 s, over noise."""
    parts, truth, t = [], [], 0.0
    for clip in clips:
        gap = np.zeros(round(rng.uniform(0.4, 1.0) * SAMPLE_RATE))
        x = fit_length(read_converted(clip.path))
        centre = energy_centroid(remove_background(x, SAMPLE_RATE), SAMPLE_RATE)
        truth.append((clip.label, t + len(gap) / SAMPLE_RATE + centre / SAMPLE_RATE))
        parts += [gap, x]
        t += (len(gap) + len(x)) / SAMPLE_RATE
    parts.append(np.zeros(SAMPLE_RATE // 2))
    signal = np.concatenate(parts)
    start = rng.integers(len(noise) - len(signal))
    return signal + NOISE_GAIN * noise[start:start + len(signal)], truth


def test_noise(data: Path) -> np.ndarray:
    """The held-out (test) part of the data set's noise files, end to end."""
    lo, hi = NOISE_REGIONS["test"]
    parts = []
    for path in sorted((data / "_background_noise_").glob("*.wav")):
        x = read_converted(path)
        parts.append(x[int(lo * len(x)):int(hi * len(x))])
    return np.concatenate(parts)


def make_recordings(data: Path, out: Path, count: int, per: int, seed: int) -> tuple:
    """`count` recordings of `per` test clips each (a fifth other words), written to `out`:
    (paths, truths, command clips used)."""
    ds = open_task_data(data, "kws12", seed, "lists", splits=("test",))
    rng = np.random.default_rng(seed)
    words = [c for c in ds.split("test") if c.label in COMMANDS]
    other = [c for c in ds.split("test") if c.label == "_unknown_"]
    noise = np.tile(test_noise(data), 4)
    paths, truths, used = [], [], []
    for k in range(count):
        n_other = per // 5
        pick = [words[i] for i in rng.choice(len(words), per - n_other, replace=False)]
        pick += [other[i] for i in rng.choice(len(other), n_other, replace=False)]
        pick = [pick[i] for i in rng.permutation(len(pick))]
        signal, truth = recording(pick, noise, rng)
        paths.append(out / f"recording-{k}.wav")
        sf.write(paths[-1], signal, SAMPLE_RATE, subtype="FLOAT")
        truths.append(truth)
        used += [c for c in pick if c.label in COMMANDS]
    return paths, truths, used


def score(results: list[dict], truths: list) -> dict:
    """Commands found (right label within TOLERANCE), detections matching nothing, and the
    timing error of those found."""
    found, false, errors, total = 0, 0, [], 0
    for r, truth in zip(results, truths):
        commands = [(w, t) for w, t in truth if w in COMMANDS]
        total += len(commands)
        taken = set()
        for d in r["detections"]:
            near = [k for k, (w, t) in enumerate(commands) if w == d["label"] and k not in taken
                    and abs(d["time"] - t) < TOLERANCE]
            if near:
                taken.add(near[0])
                errors.append(d["time"] - commands[near[0]][1])
            else:
                false += 1
        found += len(taken)
    return {"found": found, "total": total, "false": false,
            "median_abs_error": float(np.median(np.abs(errors))) if errors else None}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--model", type=Path, action="append", required=True)
    p.add_argument("--recordings", type=int, default=3)
    p.add_argument("--per", type=int, default=10, help="clips per recording")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("stream-out"))
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    paths, truths, used = make_recordings(a.data, a.out, a.recordings, a.per, a.seed)
    seconds = sum(sf.info(str(x)).duration for x in paths)
    print(f"{len(paths)} recordings, {seconds:.1f} s, {len(used)} commands "
          f"({a.data}, seed {a.seed})\n")
    print("| model | commands classified one by one | found in the stream (+-"
          f"{TOLERANCE:g} s) | false detections | median timing error | stream wall time |")
    print("|---|---|---|---|---|---|")
    for model in a.model:
        clips = classify(model, [c.path for c in used])
        right = sum(r["label"] == c.label for r, c in zip(clips, used))
        start = time.perf_counter()
        s = score(stream(model, paths, plots=a.out / model.name), truths)
        wall = time.perf_counter() - start
        err = "-" if s["median_abs_error"] is None else f"{1000 * s['median_abs_error']:.0f} ms"
        print(f"| {model.name} | {right}/{len(used)} | {s['found']}/{s['total']} | "
              f"{s['false']} | {err} | {wall:.0f} s ({wall / seconds:.2f} s per s) |",
              flush=True)


if __name__ == "__main__":
    main()
