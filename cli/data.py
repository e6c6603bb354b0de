"""`springc data synth` and `springc data info`: the offline speech corpus and a look at any
GSCD-layout data set."""

from __future__ import annotations

import os
from pathlib import Path

import click
from springc_cli.common import check_output_file, plot_option, run_user_errors

from springc.kws.data.dataset import CLASSES, PROTOCOLS, SPLITS, WORDS


@click.group("data")
def data_group() -> None:
    """Speech data for keyword spotting (GSCD layout)."""


@data_group.command("synth")
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--clips", "-n", default=2400, show_default=True, help="Clips to synthesise.")
@click.option("--seed", default=0, show_default=True, help="Seed of every random choice.")
@click.option("--jobs", "-j", default=0, help="Worker processes (0: all cores).")
@click.option("--words", default=None,
              help="Comma-separated subset of the 35 GSCD words (default: all).")
@click.option("--engines", default="espeak,flite,festival", show_default=True,
              help="Comma-separated text-to-speech engines to use.")
@plot_option
@run_user_errors
def synth_cmd(out: Path, clips: int, seed: int, jobs: int, words: str | None, engines: str,
              plot_path: str | None) -> None:
    """Write a GSCD-layout corpus into the new folder OUT from the installed text-to-speech
    engines (espeak-ng, flite, festival), with speaker-disjoint splits and background noise."""
    from springc.kws.data.synth import synthesise

    if plot_path:  # before the minutes of synthesis
        check_output_file(plot_path, make_parents=True)
    chosen = split_list(words) if words else WORDS
    report = synthesise(out, clips=clips, seed=seed, jobs=jobs or os.cpu_count() or 1,
                        words=chosen, engines=split_list(engines))
    splits = ", ".join(f"{s} {report.per_split.get(s, 0)}" for s in SPLITS)
    click.echo(f"{report.clips} clips ({splits}) from {report.voices} voices of "
               f"{report.speakers} speakers; noise files: {', '.join(report.noise_files)}")
    click.echo(f"corpus written to {report.out}")
    if plot_path:
        plot_examples(report.out, Path(plot_path))
        click.echo(f"plot written to {plot_path}")


def split_list(text: str) -> tuple[str, ...]:
    """The items of a comma-separated option."""
    return tuple(item.strip() for item in text.split(",") if item.strip())


@data_group.command("info")
@click.argument("folder", type=click.Path(path_type=Path))
@click.option("--silence", default=0.1, show_default=True,
              help="Silence clips per split, as a fraction of its word clips (training, and "
                   "validation and test under --protocol lists).")
@click.option("--protocol", type=click.Choice(PROTOCOLS), default="balanced",
              show_default=True,
              help="Held-out splits of the 12-class task: the split lists as they are, or "
                   "the paper's equal number of clips per class (as `springc train`).")
@click.option("--seed", default=0, show_default=True,
              help="Seed of the silence windows and the unknown-word subsample.")
@plot_option
@run_user_errors
def info_cmd(folder: Path, silence: float, protocol: str, seed: int,
             plot_path: str | None) -> None:
    """Count the clips of a GSCD-layout data set per split and label (12-class task); list
    bad files."""
    from springc.kws.data.dataset import open_dataset, with_protocol
    from springc.kws.training.report import counts_table

    if plot_path:
        check_output_file(plot_path, make_parents=True)
    ds = with_protocol(open_dataset(folder, silence_per_split=silence, seed=seed), protocol,
                       seed)
    click.echo(f"protocol: {protocol}")
    click.echo(counts_table(ds.counts()))
    speakers = {s: len({c.speaker for c in ds.split(s) if c.label != "_silence_"})
                for s in SPLITS}
    click.echo("speakers: " + ", ".join(f"{s} {n}" for s, n in speakers.items()))
    click.echo(f"noise files: {len(ds.noise_files)}; problems: {len(ds.problems)}")
    if plot_path:
        plot_counts(ds.counts(), Path(plot_path))
        click.echo(f"plot written to {plot_path}")


def plot_counts(counts: dict[str, dict[str, int]], path: Path) -> None:
    """A grouped bar chart of clips per label and split (PNG, written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(10, 4))
    x = np.arange(len(CLASSES))
    for k, split in enumerate(SPLITS):
        ax.bar(x + (k - 1) * 0.27, [counts[split][c] for c in CLASSES], 0.27, label=split)
    ax.set_xticks(x, CLASSES, rotation=45, ha="right")
    ax.set_ylabel("clips")
    ax.legend()
    fig.tight_layout()
    save_png(fig, path)


def plot_examples(root: Path, path: Path, count: int = 12) -> None:
    """Spectrograms of `count` clips of a corpus, spread over its words and voices (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import soundfile as sf

    files = sorted(root.glob("*/*_nohash_*.wav"))
    picked = files[:: max(len(files) // count, 1)][:count]
    fig, axes = plt.subplots(3, 4, figsize=(14, 8), squeeze=False)
    for ax, wav in zip(axes.flat, picked):
        x, rate = sf.read(str(wav))
        ax.specgram(x, NFFT=512, Fs=rate, noverlap=384, cmap="magma", vmin=-130)
        ax.set_title(f"{wav.parent.name}/{wav.name}", fontsize=8)
    for ax in axes.flat[len(picked):]:
        ax.axis("off")
    fig.supxlabel("time (s)")
    fig.supylabel("frequency (Hz)")
    fig.tight_layout()
    save_png(fig, path)


def save_png(fig, path: Path) -> None:
    """Write a figure atomically (temporary file, then rename) and close it."""
    import matplotlib.pyplot as plt

    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)


COMMANDS = [data_group]
