"""`springc classify --stream` and the mass-spring network through `classify`: detections on a
long recording made of known clips and silence land at the words' known times; a window's
decision is the clip's decision (digital windows, and the simulated network's readout
increase over one clip horizon, at the first clip and at a later one); the network's clip
scores are those eval computes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner

from springc.kws.features import massspring as msp
from springc.kws.evaluation import stream as st
from springc.kws.evaluation.classify import CLIP_SECONDS, feature_rows
from springc.kws.data.dataset import load_clip
from springc.kws.evaluation.evaluate import model_integration, simulate_network
from springc.kws.training.model import load_model
from springc.kws.data.preprocess import energy_centroid
from springc.kws.data.task import open_task_data
from springc.kws.training.transfer import model_heads
from springc.lang import load_file
from springc_cli.main import main
from kws_corpora import RATE, make_corpus, word_sound
from shared_cache import KERNELS

WORDS = ("yes", "cat", "no", "yes", "no")  # cat is _unknown_: never a detection
GAP = 0.7  # s of near-silence before, between and after the clips


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """A tiny corpus, a 4 x 2 digital model and a 2 x 2 mass-spring model trained on it (the
    paper's integration, no choice: a minute on a cold kernel cache), a long recording."""
    root = tmp_path_factory.mktemp("stream")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(KERNELS))
        data = make_corpus(root / "data")
        for name, args in (("digital", ["-n", "4", "-m", "2"]),
                           ("ms", ["-n", "2", "-m", "2", "--realisation", "mass-spring",
                                   "--paper-steps"])):
            result = CliRunner().invoke(main, ["train", "--data", str(data), "-j", "1", *args,
                                               "-o", str(root / name)])
            assert result.exit_code == 0, result.output
        yield root, data, long_recording(root / "long.wav")


def long_recording(path: Path) -> list[tuple[str, float]]:
    """WORDS spoken one clip each between GAP s of faint noise, written to `path`: the
    (word, time of its energy centre) of each."""
    rng = np.random.default_rng(11)
    parts, truth, t = [], [], 0.0
    for word in WORDS:
        parts.append(np.zeros(round(GAP * RATE)))
        t += GAP
        clip = word_sound(word, rng)
        truth.append((word, t + energy_centroid(clip, RATE) / RATE))
        parts.append(clip)
        t += CLIP_SECONDS
    parts.append(np.zeros(round(GAP * RATE)))
    x = np.concatenate(parts)
    sf.write(path, x + 0.003 * rng.normal(size=len(x)), RATE, subtype="PCM_16")
    return truth


def streamed(model: Path, wav: Path, plots: Path) -> dict:
    result = CliRunner().invoke(main, ["classify", str(model), str(wav), "--stream", "--json",
                                       "--plots", str(plots)])
    assert result.exit_code == 0, result.output
    (got,) = json.loads(result.stdout)
    return got


@pytest.mark.parametrize("name", ["digital", "ms"])
def test_detections_land_at_the_known_times(env, tmp_path, name):
    """Both realisations find the four commands, in order, within 0.1 s of each word's energy
    centre, and not the `cat` (_unknown_); the plot is written."""
    root, _, truth = env
    got = streamed(root / name, root / "long.wav", tmp_path / "plots")
    keywords = [(w, t) for w, t in truth if w != "cat"]
    assert [d["label"] for d in got["detections"]] == [w for w, _ in keywords]
    for d, (_, t) in zip(got["detections"], keywords):
        assert abs(d["time"] - t) < 0.1, (d, t)
        assert d["start"] < d["time"] < d["end"] and d["score"] > 0
    assert got["seconds"] == pytest.approx(len(WORDS) * (GAP + CLIP_SECONDS) + GAP)
    png = Path(got["plot"])
    assert png == tmp_path / "plots" / "long.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_a_digital_window_is_a_clip(env):
    """The window centred at 0.5 s of a one-clip recording is that clip: its decisions equal
    the clip's, and the trace runs from 0 to the end in HOP steps."""
    root, data, _ = env
    model = load_model(root / "digital")
    clip = held_out_words(data)[0]
    x = load_clip(clip)
    trace = st.digital_trace(model, x)
    np.testing.assert_allclose(trace.times, np.arange(11) * st.HOP, atol=1e-12)
    np.testing.assert_allclose(trace.rows[5], feature_rows(model, x[None])[0], rtol=1e-9)


def test_detections_are_runs_timed_by_their_decisions():
    """The rule on a made-up trace: runs of one command with a positive decision, at least
    MIN_RUN long, timed by the decision-weighted mean of their centres; _unknown_ and
    negative decisions never detect, a one-window blip is dropped."""
    names = ["yes", "no", "_unknown_"]
    times = np.arange(12) * 0.1
    rows = np.full((12, 3), -1.0)
    rows[1:5, 0] = [1.0, 3.0, 3.0, 1.0]  # yes, 0.1-0.4 s: centre 0.25
    rows[5, 1] = 2.0  # a blip of no: too short
    rows[7:10, 2] = 5.0  # _unknown_
    rows[10:12, 1] = -0.5  # no is the argmax but negative
    rows[10:12, 0] = -0.6
    rows[10:12, 2] = -0.7
    (d,) = st.detections(st.Trace(times, rows, names))
    assert d == {"label": "yes", "time": pytest.approx(0.25), "start": pytest.approx(0.1),
                 "end": pytest.approx(0.4), "score": 3.0}


def held_out_words(data: Path) -> list:
    return [c for c in open_task_data(data, "kws12", protocol="lists",
                                      splits=("test",)).split("test")
            if c.label != "_silence_"]


def network_decisions(model, signals: np.ndarray) -> np.ndarray:
    """What eval computes: the whole classifier simulated on clips, row decisions."""
    s, heads = model_heads(model)
    net = load_file(model.folder / "classifier.spr")
    return simulate_network(net, heads, s, signals.astype(np.float32), jobs=1,
                            plan=model_integration(model))[0]


def test_network_scores_are_evals(env):
    """classify with a mass-spring model simulates the whole network: its scores are the
    decisions eval's simulation gives the same clips."""
    root, data, _ = env
    model = load_model(root / "ms")
    clips = held_out_words(data)
    want = network_decisions(model, np.stack([load_clip(c) for c in clips]))
    result = CliRunner().invoke(main, ["classify", str(root / "ms"), "--json", "-j", "1",
                                       *[str(c.path) for c in clips]])
    assert result.exit_code == 0, result.output
    got = json.loads(result.stdout)
    classes = list(model.models[0][0])
    for g, d in zip(got, want):
        np.testing.assert_allclose([g["scores"][c] for c in classes], d, rtol=1e-9)
        assert g["label"] == classes[int(np.argmax(d))]


def test_the_readout_increase_is_a_later_clips_decision(env):
    """Two clips with a clip horizon of silence between them, through the network once: the
    window ending one horizon after the first clip started reads the first clip's decision
    (the network started at rest), and the window over the second clip reads the second
    clip's own decision, although the readouts still hold the first (tau = 80 s); without
    subtracting the decayed readout it would be far off."""
    root, data, _ = env
    model = load_model(root / "ms")
    s, heads = model_heads(model)
    a, b = (load_clip(c) for c in held_out_words(data)[:2])
    horizon = msp.horizon(s, CLIP_SECONDS)
    start = round((CLIP_SECONDS + horizon) * RATE)  # b starts here: a has settled
    signal = np.zeros(start + len(b))
    signal[:len(a)], signal[start:] = a, b
    want = network_decisions(model, np.stack([a, b]))
    t, x = st.network_readouts(model, signal)
    lag = round(horizon * st.READOUT_RATE)
    rows = st.readout_decisions(x, lag, math.exp(-st.slow_pole() * lag / st.READOUT_RATE),
                                heads)
    end_b = round(start / RATE * st.READOUT_RATE) + lag
    assert t[lag] == pytest.approx(horizon) and t[end_b] == pytest.approx(start / RATE + horizon)
    np.testing.assert_allclose(rows[lag], want[0], rtol=1e-6)
    # the network has not quite returned to rest from the first clip when the second's
    # window opens (in the silence between them the readouts drift by up to 0.1% more than
    # their slow pole accounts for): 7e-4 of the largest decision measured, against 1.6
    # without subtracting the decayed readout
    scale = np.abs(want).max()
    np.testing.assert_allclose(rows[end_b], want[1], rtol=0, atol=2e-3 * scale)
    raw = np.array([x[k, end_b] / h.scale + h.intercept for k, h in enumerate(heads)])
    assert np.abs(raw - want[1]).max() > 10 * 2e-3 * scale


def test_a_mass_spring_models_readme(env):
    """The mass-spring model folder explains itself too: the network files, both
    integrations, and a training command with every setting (no setting left out)."""
    root, data, _ = env
    text = (root / "ms" / "README.md").read_text()
    (line,) = [x for x in text.splitlines() if x.startswith("springc train ")]
    for option in ("--realisation mass-spring", "-n 2 -m 2", "--threshold 0.001",
                   "--epsilon 1e-05", "--paper-steps"):
        assert option in line
    assert "has no option for" not in text
    assert "feature network integrated by rk4 x8 float32 (set, not measured)" in text
    assert "`springc eval` simulates the whole classifier network" in text
    for name in ("classifier.spr", "features.spr", "head0.spr", "head3.spr"):
        assert f"- `{name}`: " in text


def test_the_energy_budget_reads_a_test_only_folder(env, tmp_path):
    """`eval --budget` needs the test split alone too: on a copy of the test clips without
    split lists it prints the table the training folder's test split gives."""
    import shutil

    from springc.kws.evaluation import energy
    from springc.kws.evaluation.evaluate import budget_signals

    root, data, _ = env
    for clip in held_out_words(data)[:2]:
        (tmp_path / "t" / clip.word).mkdir(parents=True, exist_ok=True)
        shutil.copy(clip.path, tmp_path / "t" / clip.word / clip.path.name)
    result = CliRunner().invoke(main, ["eval", str(root / "ms"), "--data", str(tmp_path / "t"),
                                       "--budget", "2", "--protocol", "lists"])
    assert result.exit_code == 0, result.output
    want = energy.budget_table(energy.model_budget(root / "ms", budget_signals(root / "ms",
                                                                                data, 2)))
    assert result.stdout.splitlines()[1:1 + len(want)] == want
    assert result.stdout.startswith("energy budget of the whole classifier, 2 test clips")
