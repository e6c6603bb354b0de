"""Every command refuses what build refuses, and no input gets a traceback (issue 23).

1. Golden error cases: each `tests/cases/err/*.spr` through every netlist-reading command
   (build, sim, ac, modes, export) exits 1 with the first line `springc build` prints for it.
2. Fuzz: every variant of `netlist_cases.VARIANTS` (over 1600: example, ok-case and library
   netlists, 16 operators) through all five commands, so five invocations per variant (counts
   asserted in `test_fuzz_counts`): each exits 0 with its output written, or 1 with a located
   message and no output file; a refused variant gets the same first line from every command.
3. Broken non-netlist inputs (over 100, `BROKEN`), each to the command that reads it: sound
   files for `sim -i`, `export --input` and a netlist's wav() source; data set folders for
   `data info`, `train --data` and `eval --data`; model folders for `eval`; `.npy` matrices
   for `design mvm`; unwritable outputs (an existing folder, a path under a file, a folder
   that is not a model) for every command that writes one. Each exits 1 with a message naming
   the file, or (an existing folder given for an output file) 2 from click's own check, before
   any work; never a traceback, never a partial output.
4. Broken `.step`/`.mc` netlists and thermal-noise misuse (issues 38 and 39, `POPULATION`)
   through every command that reads a netlist (build, sim, ac, modes, noise, grad, export):
   each exits 1 with the same located first line, the point named where a point fails,
   no output file, and no kernel compiled (the errors come before any). `--temp` and the
   noise band given on the command line (`OPTION_MISUSE`) are refused by name likewise.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner
from netlist_cases import ERR, VARIANTS, materialise

from springc_cli.main import main

COMMANDS = ("build", "sim", "ac", "modes", "export")
LOCATED = re.compile(r"^\S+\.spr:\d+:\d+: error: ", re.M)
NAMED = re.compile(r"^error: \S.*: ", re.M)  # a DataError: `error: PATH: reason`
PROBE = re.compile(r"\.probe\s+[xv]\(([^)\s]+)\)")


def run(args: list[str]) -> tuple[int, str]:
    """Exit code and everything printed (stdout and stderr) of one in-process invocation."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    output = result.output  # stdout and stderr interleaved (click >= 8.2)
    assert "Traceback" not in output and "INTERNAL ERROR" not in output, output
    return result.exit_code, output


def command_args(command: str, netlist: Path, out: Path, node: str = "x") -> tuple[list, Path]:
    """The argument list of a netlist-reading command and the file it writes (or None)."""
    table = {
        "build": (["build", netlist, "--emit-kernel", out / "k.py"], out / "k.py"),
        "sim": (["sim", netlist, "-o", out / "o.npz"], out / "o.npz"),
        "ac": (["ac", netlist, "--node", node, "-o", out / "o.csv"], out / "o.csv"),
        "modes": (["modes", netlist], None),
        "export": (["export", netlist, "--spice", "-o", out / "o.cir"], out / "o.cir"),
    }
    return table[command]


def first_line(output: str) -> str:
    """The first line that is not a progress bar."""
    return next((s for s in output.splitlines() if "error" in s), output.split("\n", 1)[0])


def outcome(command: str, netlist: Path, out: Path, node: str = "x") -> tuple[int, str]:
    """Run one command; assert exit 0 with the output written, or 1 with a located or named
    message and no output file. Returns (exit code, first error line)."""
    args, written = command_args(command, netlist, out, node)
    code, output = run(args)
    if code == 0:
        assert written is None or written.is_file(), output
        if written is not None:
            written.unlink()
        return 0, ""
    assert code == 1, output
    assert LOCATED.search(output) or NAMED.search(output), output
    assert written is None or not written.exists(), output
    return 1, first_line(output)


# -- 1. golden error cases -------------------------------------------------------------------


@pytest.mark.parametrize("case", ERR, ids=lambda p: p.stem)
def test_every_command_refuses_an_error_case_as_build_does(case, tmp_path):
    expected = outcome("build", case, tmp_path)
    assert expected[0] == 1 and LOCATED.match(expected[1]), expected
    for command in COMMANDS[1:]:
        assert outcome(command, case, tmp_path) == expected, command


# -- 2. fuzz ---------------------------------------------------------------------------------


def test_fuzz_counts():
    """Every variant goes through all five commands: the invocations per command."""
    per_command = {c: len(VARIANTS) for c in COMMANDS}
    assert len(VARIANTS) >= 500 and sum(per_command.values()) >= 2500, per_command


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.parametrize("index", range(len(VARIANTS)), ids=[v[0] for v in VARIANTS])
def test_fuzz_variant_through_every_command(fuzz_dir, index):
    name, original, text = VARIANTS[index]
    # Library variants change a shared file: a folder each; the rest share their source's.
    folder = fuzz_dir / (name if original.parent.name == "lib" else original.parent.name)
    netlist = materialise(folder, name, original, text)
    out = fuzz_dir / f"out-{index}"
    out.mkdir()
    probe = PROBE.search(netlist.read_text())
    lines = {c: outcome(c, netlist, out, probe[1] if probe else "x") for c in COMMANDS}
    if lines["build"][0] == 1:  # build refuses it: so does every command, with its words
        assert set(lines.values()) == {lines["build"]}, lines
    shutil.rmtree(out)


# -- 3. broken non-netlist inputs ------------------------------------------------------------

DRIVEN = "M1 x m=1 b=1\nK1 x k=100\nF1 x {src} gain=1\n.probe x(x)\n.tran 1ms 0.1\n"
RATE = 16000


def _wav_bytes(x: np.ndarray, rate: int = RATE, subtype: str = "PCM_16") -> bytes:
    import io

    buf = io.BytesIO()
    sf.write(buf, x, rate, subtype=subtype, format="WAV")
    return buf.getvalue()


def _npz_bytes(**arrays) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _tone(n: int = 1600) -> np.ndarray:
    return 0.3 * np.sin(np.arange(n) / 5.0)


def _with(x: np.ndarray, index: int, value: float) -> np.ndarray:
    y = x.copy()
    y[index] = value
    return y


def broken_audio() -> dict[str, bytes]:
    """File name -> content of sound files that no command may read."""
    good = _wav_bytes(_tone())
    rng = np.random.default_rng(0)
    stereo = np.stack([_tone(), _with(_tone(), 7, np.nan)], axis=1)
    return {
        "empty.wav": b"",
        "header-cut.wav": good[:20],
        "header-only.wav": good[:44],
        "data-cut.wav": good[:1000],
        "data-cut-odd.wav": good[:1001],
        "text.wav": b"this is not a sound file\n",
        "random.wav": rng.bytes(4000),
        "png.wav": b"\x89PNG\r\n\x1a\n" + bytes(200),
        "zip.wav": _npz_bytes(a=np.arange(10)),
        "riff-garbage.wav": b"RIFF" + struct.pack("<I", 1000) + b"WAVE" + rng.bytes(100),
        "no-frames.wav": _wav_bytes(np.zeros(0)),
        "nan-float.wav": _wav_bytes(_with(_tone(), 100, np.nan), subtype="FLOAT"),
        "inf-float.wav": _wav_bytes(_with(_tone(), 0, np.inf), subtype="FLOAT"),
        "minus-inf-double.wav": _wav_bytes(_with(_tone(), 5, -np.inf), subtype="DOUBLE"),
        "nan-last.wav": _wav_bytes(_with(_tone(), -1, np.nan), subtype="FLOAT"),
        "nan-in-channel-1.wav": _wav_bytes(stereo, subtype="FLOAT"),
        "garbage.flac": rng.bytes(3000),
        "garbage.ogg": b"OggS" + rng.bytes(3000),
    }


MULTI_CHANNEL = {"eight-channels.wav": 8, "stereo.wav": 2}  # refused by in(k) inputs only


class Kit:
    """The inputs of the broken-input cases, made once per module in `root`."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.audio = root / "audio"
        self.audio.mkdir()
        for name, data in broken_audio().items():
            (self.audio / name).write_bytes(data)
            (self.audio / f"wav-{name}.spr").write_text(
                DRIVEN.format(src=f'wav("{name}")'))
        for name, nch in MULTI_CHANNEL.items():
            sf.write(self.audio / name, np.tile(_tone()[:, None], (1, nch)), RATE)
        (self.audio / "no-audio").mkdir()
        (self.audio / "no-audio" / "notes.txt").write_text("no sound here\n")
        (self.audio / "one-bad").mkdir()
        (self.audio / "one-bad" / "a.wav").write_bytes(_wav_bytes(_tone()))
        (self.audio / "one-bad" / "b.wav").write_bytes(b"RIFF")
        self.driven = root / "driven.spr"
        self.driven.write_text(DRIVEN.format(src="in(0)"))
        self.afile = root / "a-file"
        self.afile.write_text("a regular file where a folder should be\n")
        self.folder = root / "a-folder"
        self.folder.mkdir()
        self.not_model = root / "not-a-model"
        self.not_model.mkdir()
        (self.not_model / "thesis.tex").write_text("precious\n")

    def out(self, name: str) -> Path:
        """A fresh output folder for one case."""
        path = self.root / "out" / name
        path.mkdir(parents=True)
        return path


# A case: (args, text the message must hold, paths that must not exist afterwards, whether
# the path is one that click's own check refused with exit 2 before the commands checked
# their paths themselves: kept to name those cases, all of which now exit 1).
Case = tuple[list, str, list, bool]


def audio_cases() -> dict[str, object]:
    cases = {}
    for name in [*broken_audio(), *MULTI_CHANNEL, "absent.wav", "no-audio", "one-bad"]:
        def sim(k: Kit, name=name) -> Case:
            out = k.out(f"sim-i-{name}")
            return (["sim", k.driven, "-i", k.audio / name, "-o", out / "o.npz"],
                    str(k.audio / name), [out / "o.npz"], False)

        def export(k: Kit, name=name) -> Case:
            out = k.out(f"export-input-{name}")
            return (["export", k.driven, "--spice", "--input", k.audio / name, "-o",
                     out / "o.cir"], str(k.audio / name), [out / "o.cir"], True)

        cases[f"sim-input-{name}"] = sim
        cases[f"export-input-{name}"] = export
    for name in broken_audio():
        def wav_source(k: Kit, name=name) -> Case:
            out = k.out(f"wav-{name}")
            return (["sim", k.audio / f"wav-{name}.spr", "-o", out / "o.npz"],
                    name, [out / "o.npz"], False)

        cases[f"wav-source-{name}"] = wav_source
    return cases


BROKEN: dict[str, object] = {**audio_cases()}


@pytest.fixture(scope="module")
def kit(tmp_path_factory) -> Kit:
    """The inputs, a tiny corpus and a model trained on it (4 bins x 2 delays, seconds)."""
    from kws_corpora import make_corpus

    k = Kit(tmp_path_factory.mktemp("broken"))
    k.data = broken_data(k.root / "data")
    k.corpus = make_corpus(k.root / "corpus")
    k.model = k.root / "model"
    code, output = run(["train", "--data", k.corpus, "-n", "4", "-m", "2", "-j", "1", "-o",
                        k.model])
    assert code == 0, output
    return k


def _split_lists(root: Path, validation: str = "", testing: str = "") -> Path:
    (root / "validation_list.txt").write_text(validation)
    (root / "testing_list.txt").write_text(testing)
    return root


def _word(root: Path, files: dict[str, bytes], word: str = "yes") -> Path:
    (root / word).mkdir(parents=True)
    for name, data in files.items():
        (root / word / name).write_bytes(data)
    return root


def broken_data(root: Path) -> dict[str, Path]:
    """Name -> a data set folder that no command may read."""
    good = _wav_bytes(_tone(RATE))
    bad = broken_audio()
    root.mkdir()
    sets = {"absent": root / "absent", "a-file": root / "a-file", "empty": root / "empty"}
    sets["a-file"].write_text("not a folder\n")
    sets["empty"].mkdir()
    (root / "noise-only" / "_background_noise_").mkdir(parents=True)
    sets["noise-only"] = root / "noise-only"
    sets["no-audio"] = _split_lists(_word(root / "no-audio", {"notes.txt": b"words\n"}))
    sets["broken-audio"] = _split_lists(_word(root / "broken-audio", {
        f"s{i}_nohash_0.wav": bad[name] for i, name in enumerate(
            ["empty.wav", "text.wav", "data-cut.wav", "nan-float.wav", "inf-float.wav",
             "header-cut.wav", "no-frames.wav"])}))
    sets["low-rate"] = _split_lists(_word(root / "low-rate", {
        "s0_nohash_0.wav": _wav_bytes(_tone(10), rate=1)}))
    sets["no-lists"] = _word(root / "no-lists", {"s0_nohash_0.wav": good})
    sets["binary-list"] = _split_lists(_word(root / "binary-list", {"s0_nohash_0.wav": good}))
    (sets["binary-list"] / "validation_list.txt").write_bytes(b"\xff\xfe\x00garbage")
    sets["bad-line"] = _split_lists(_word(root / "bad-line", {"s0_nohash_0.wav": good}),
                                    validation="not a path\n")
    sets["list-is-folder"] = _word(root / "list-is-folder", {"s0_nohash_0.wav": good})
    (sets["list-is-folder"] / "validation_list.txt").mkdir()
    (sets["list-is-folder"] / "testing_list.txt").write_text("")
    sets["in-both-lists"] = _split_lists(_word(root / "in-both-lists", {"s0_nohash_0.wav": good}),
                                         "yes/s0_nohash_0.wav\n", "yes/s0_nohash_0.wav\n")
    return sets


DATA_SETS = ("absent", "a-file", "empty", "noise-only", "no-audio", "broken-audio", "low-rate",
             "no-lists", "binary-list", "bad-line", "list-is-folder", "in-both-lists")


def data_cases() -> dict[str, object]:
    cases = {}
    for name in DATA_SETS:
        def info(k: Kit, name=name) -> Case:
            return ["data", "info", k.data[name]], str(k.data[name]), [], False

        def train(k: Kit, name=name) -> Case:
            out = k.out(f"train-data-{name}") / "model"
            return (["train", "--data", k.data[name], "-n", "4", "-m", "2", "-j", "1", "-o", out],
                    str(k.data[name]), [out], False)

        def evaluate(k: Kit, name=name) -> Case:
            return (["eval", k.model, "--data", k.data[name], "-j", "1"], str(k.data[name]), [],
                    False)

        cases.update({f"data-info-{name}": info, f"train-data-{name}": train})
        if name not in EVALUABLE:
            cases[f"eval-data-{name}"] = evaluate
    return cases


# Evaluating needs the test split alone: a folder without split lists is all test clips
# (tests/test_kws_eval_folder.py), so eval reads it while data info and train refuse it.
EVALUABLE = ("no-lists",)


def _edit_json(path: Path, change) -> None:
    settings = json.loads(path.read_text())
    change(settings)
    path.write_text(json.dumps(settings))


def _edit_weights(path: Path, change) -> None:
    with np.load(path) as w:
        arrays = dict(w)
    change(arrays)
    path.unlink()
    np.savez(path, **arrays)


MODEL_DAMAGE = {  # name -> (file damaged, how)
    "no-settings": ("settings.json", lambda p: p.unlink()),
    "no-weights": ("weights.npz", lambda p: p.unlink()),
    "no-report": ("report.json", lambda p: p.unlink()),
    "settings-cut": ("settings.json", lambda p: p.write_bytes(p.read_bytes()[:40])),
    "settings-binary": ("settings.json", lambda p: p.write_bytes(b"\xff\xfe\x00\x01garbage")),
    "settings-empty": ("settings.json", lambda p: p.write_bytes(b"")),
    "settings-list": ("settings.json", lambda p: p.write_text("[1, 2, 3]")),
    "settings-null": ("settings.json", lambda p: p.write_text("null")),
    "settings-folder": ("settings.json", lambda p: (p.unlink(), p.mkdir())),
    "no-features": ("settings.json", lambda p: _edit_json(p, lambda s: s.pop("features"))),
    "features-list": ("settings.json",
                      lambda p: _edit_json(p, lambda s: s.update(features=[4, 2]))),
    "bins-text": ("settings.json",
                  lambda p: _edit_json(p, lambda s: s["features"].update(bins="four"))),
    "bins-mismatch": ("weights.npz", lambda p: _edit_json(  # weights of another size
        p.parent / "settings.json", lambda s: s["features"].update(bins=6))),
    "realisation-number": ("settings.json",
                           lambda p: _edit_json(p, lambda s: s.update(realisation=3))),
    "realisation-unknown": ("settings.json",
                            lambda p: _edit_json(p, lambda s: s.update(realisation="quantum"))),
    "version-newer": ("settings.json",
                      lambda p: _edit_json(p, lambda s: s.update(springc_version="99.0.0"))),
    "version-garbage": ("settings.json",
                        lambda p: _edit_json(p, lambda s: s.update(springc_version="banana"))),
    "weights-cut": ("weights.npz", lambda p: p.write_bytes(p.read_bytes()[:300])),
    "weights-garbage": ("weights.npz", lambda p: p.write_bytes(bytes(range(256)) * 4)),
    "weights-empty": ("weights.npz", lambda p: p.write_bytes(b"")),
    "weights-npy": ("weights.npz", lambda p: np.save(open(p, "wb"), np.arange(5))),
    "weights-no-coef": ("weights.npz", lambda p: _edit_weights(p, lambda a: a.pop("coef_raw"))),
    "weights-1d": ("weights.npz",
                   lambda p: _edit_weights(p, lambda a: a.update(coef_raw=a["coef_raw"][0]))),
    "weights-nan": ("weights.npz", lambda p: _edit_weights(
        p, lambda a: a.update(coef_raw=np.full_like(a["coef_raw"], np.nan)))),
    "weights-rows": ("weights.npz",
                     lambda p: _edit_weights(p, lambda a: a.update(rows=-a["rows"]))),
    "weights-classes": ("weights.npz", lambda p: _edit_weights(
        p, lambda a: a.update(classes=np.array(["yes,no"])))),
    "weights-pickle": ("weights.npz", lambda p: _edit_weights(
        p, lambda a: a.update(classes=np.array([{"x": 1}], dtype=object)))),
}


def model_cases() -> dict[str, object]:
    cases = {}
    for name, (file, damage) in MODEL_DAMAGE.items():
        def evaluate(k: Kit, name=name, file=file, damage=damage) -> Case:
            folder = k.root / "models" / name
            shutil.copytree(k.model, folder)
            damage(folder / file)
            return ["eval", folder, "--data", k.corpus, "-j", "1"], str(folder / file), [], False

        cases[f"eval-model-{name}"] = evaluate
    for name in ("absent", "a-file", "empty"):
        def whole(k: Kit, name=name) -> Case:
            folder = {"absent": k.root / "no-model", "a-file": k.afile, "empty": k.folder}[name]
            return ["eval", folder, "--data", k.corpus], str(folder), [], False

        cases[f"eval-model-{name}"] = whole
    return cases


BROKEN.update(data_cases())
BROKEN.update(model_cases())


def _npy_bytes(a: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=True)
    return buf.getvalue()


BROKEN_MATRICES = {
    "absent.npy": None,
    "empty.npy": b"",
    "text.npy": b"1 0\n0 1\n",
    "cut.npy": _npy_bytes(np.eye(4))[:100],
    "npz.npy": _npz_bytes(q=np.eye(2)),
    "nan.npy": _npy_bytes(np.full((2, 2), np.nan)),
    "inf.npy": _npy_bytes(np.array([[np.inf, 0.0], [0.0, 1.0]])),
    "object.npy": _npy_bytes(np.array([{"a": 1}], dtype=object)),
    "cube.npy": _npy_bytes(np.zeros((2, 2, 2))),
    "zero-size.npy": _npy_bytes(np.zeros((0, 0))),
    "not-orthogonal.npy": _npy_bytes(np.ones((2, 2))),
    "complex.npy": _npy_bytes(np.eye(2, dtype=complex)),
}


def matrix_cases() -> dict[str, object]:
    cases = {}
    for name, data in BROKEN_MATRICES.items():
        def mvm(k: Kit, name=name, data=data) -> Case:
            out = k.out(f"mvm-{name}")
            if data is not None:
                (out / name).write_bytes(data)
            return (["design", "mvm", "--matrix", out / name, "-o", out / "mvm.spr"],
                    str(out / name), [out / "mvm.spr"], False)

        cases[f"design-mvm-{name}"] = mvm
    return cases


def _outputs(k: Kit, name: str) -> list:
    """Per writing command: its arguments before the output option, and that option."""
    good = k.audio.parent / "good.npy"
    if not good.exists():
        np.save(good, np.eye(2))
    return {
        "sim": ["sim", k.driven, "-o"],
        "ac": ["ac", k.driven, "--node", "x", "-o"],
        "export": ["export", k.driven, "--spice", "-o"],
        "build": ["build", k.driven, "--emit-kernel"],
        "design-lowpass": ["design", "lowpass", "--fc", "50", "-o"],
        "design-readout": ["design", "readout", "--tau", "1", "-o"],
        "design-melbank": ["design", "melbank", "--bins", "4", "-o"],
        "design-mvm": ["design", "mvm", "--matrix", good, "-o"],
    }[name]


SUFFIX = {"sim": ".npz", "ac": ".csv", "export": ".cir", "build": ".py"}
WRITERS = ("sim", "ac", "export", "build", "design-lowpass", "design-readout", "design-melbank",
           "design-mvm")


def output_cases() -> dict[str, object]:
    cases = {}
    for name in WRITERS:
        def into_folder(k: Kit, name=name) -> Case:
            return [*_outputs(k, name), k.folder], str(k.folder), [], True

        def under_file(k: Kit, name=name) -> Case:
            path = k.afile / f"out{SUFFIX.get(name, '.spr')}"
            return [*_outputs(k, name), path], str(k.afile), [], False

        cases[f"output-folder-{name}"] = into_folder
        cases[f"output-under-file-{name}"] = under_file
    for name in ("sim", "ac", "export", "design-melbank"):  # unwritable plot: nothing written
        def plot(k: Kit, name=name) -> Case:
            out = k.out(f"plot-{name}")
            main_out = out / f"o{SUFFIX.get(name, '.spr')}"
            return ([*_outputs(k, name), main_out, "--plot", k.afile / "p.png"], str(k.afile),
                    [main_out], False)

        cases[f"plot-under-file-{name}"] = plot

    def train_to(k: Kit, where: str) -> Case:
        target = {"file": k.afile, "under-file": k.afile / "sub" / "model",
                  "not-a-model": k.not_model}[where]
        return (["train", "--data", k.corpus, "-n", "4", "-m", "2", "-j", "1", "-o", target],
                str(target if where != "under-file" else k.afile), [], False)

    for where in ("file", "under-file", "not-a-model"):
        cases[f"train-out-{where}"] = lambda k, where=where: train_to(k, where)
    return cases


BROKEN.update(matrix_cases())
BROKEN.update(output_cases())


def test_enough_broken_inputs():
    assert len(BROKEN) >= 100, len(BROKEN)


# Known failures, each an xfail that must stay strict (none today).
KNOWN: dict[str, str] = {}  # case -> why it fails today (an xfail that must stay strict)


@pytest.mark.parametrize("case", [
    pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=KNOWN[c])) if c in KNOWN else c
    for c in sorted(BROKEN)])
def test_broken_input_is_a_named_user_error(kit, case):
    args, named, absent, _ = BROKEN[case](kit)
    code, output = run(args)
    assert code == 1, output  # a folder given as an output file too (no click usage error)
    assert LOCATED.search(output) or NAMED.search(output), output
    assert named in output, output
    for path in absent:
        assert not path.exists(), output
    assert (kit.not_model / "thesis.tex").is_file()  # a folder not a model is never replaced


# -- 4. populations and thermal noise ----------------------------------------------------------

BASE = """* a driven resonator
.param k0=4
M1 a m=1 b=0.5
K1 a k={k0}
F1 a in(0) gain=1
.probe x(a)
.tran 10m 1
"""
PAIR = """.subckt pair p q kc=1
C1 p q k={kc}
.ends
M2 c m=1 b=0.5
X1 a c pair
"""
# name -> (lines added to BASE, line:col of the error, words the message holds)
POPULATION = {
    "step-unknown-param": (".step kx list 1 2\n", "8:7", "unknown parameter 'kx'"),
    "step-subckt-param": (PAIR + ".step kc list 1 2\n", "13:7",
                          "'kc' is not a top-level parameter"),
    "step-loop-variable": (".for i 1 2\nM{i}x n{i} m=1\n.endfor\n.step i list 1 2\n",
                           "11:7", "'i' is not a top-level parameter"),
    "step-inside-subckt": (".subckt s p\n.step k0 list 1 2\n.ends\n", "9:1",
                           ".step is only allowed at the top level"),
    "step-empty-list": (".step k0 list\n", "8:1", ".step k0 list has no values"),
    "step-zero-increment": (".step k0 1 2 0\n", "8:14", "the increment is zero"),
    "step-wrong-way": (".step k0 1 2 -1\n", "8:14", "never reaches 2"),
    "step-log-from-zero": (".step k0 dec 0 10 2\n", "8:14", "the start must be > 0"),
    "step-twice": (".step k0 list 1 2\n.step k0 list 3\n", "9:1", "given twice"),
    "step-random-value": (".step k0 list {gauss(1, 0.1)} 2\n", "8:16", "cannot be used in "
                          "a .step line"),
    "mc-negative-count": (".mc -3\n", "8:5", "the .mc count must be >= 1, got -3"),
    "mc-zero-count": (".mc 0\n", "8:5", "the .mc count must be >= 1, got 0"),
    "mc-twice": (".mc 2\n.mc 3\n", "9:1", "a second .mc"),
    "mc-negative-seed": (".mc 2 seed=-1\n", "8:12", "seed must be an integer >= 0"),
    "random-in-tran": (".param t1={gauss(1, 0.1)}\n.tran 10m {unif(1, 0.1)}\n.mc 2\n",
                       "9:12", "unif() cannot be used in a .tran line"),
    "random-negative-spread": (".param m0={gauss(1, -0.1)}\nM9 z m={m0}\n", "8:12",
                               "gauss(): rvar must be >= 0"),
    "mc-spread-breaks-a-sign": (
        ".param m0={gauss(1, 0.8)}\nM9 z m={m0}\n.mc 50 seed=2\n", "9:1",
        "M9: mass m=-0.905171 must be > 0 at point 34 of 50 (sample 34, seed 2)"),
    "step-breaks-a-sign": (".step k0 list 1 -2\n", "4:1",
                           "K1: stiffness k=-2 must be >= 0 at point 1 of 2 (k0=-2)"),
    "step-and-mc-break-a-sign": (
        ".param g={agauss(0, 1)}\nK2 a k={k0 * g}\n.step k0 list 1 2\n.mc 3 seed=1\n",
        "9:1", "K2: stiffness k=-0.266159 must be >= 0 at point 0 of 6 (k0=1, sample 0, "
               "seed 1)"),
    "temp-negative": (".options temp=-1\n", "8:15", "temp must be a finite temperature"),
    "temp-overflow": (".options temp={1e308*10}\n", "8:21", "the result is inf"),
    "noise-unknown-node": (".noise zz 1 100\n", "8:8", "node 'zz' has no mass"),
    "noise-band-reversed": (".noise a 10 1\n", "8:10", "needs 0 < fstart <= fstop"),
    "noise-band-from-zero": (".noise a 0 100\n", "8:10", "needs 0 < fstart <= fstop"),
    "noise-band-one-point": (".noise a 1 10 points=1\n", "8:1", "needs points >= 2"),
    "noise-no-damper": (".noise a 1 10\n", "8:1", "the netlist has no damper"),
    "temp-no-damper": (".options temp=300\n", "8:10", "but the netlist has no damper"),
}
UNDAMPED = ("noise-no-damper", "temp-no-damper")
POPULATION_COMMANDS = ("build", "sim", "ac", "modes", "noise", "grad", "export")


def population_args(command: str, netlist: Path, out: Path) -> tuple[list, list[Path]]:
    """A command's arguments on `netlist` and every file it could write."""
    table = {
        "build": (["build", netlist, "--emit-kernel", out / "k.py"], [out / "k.py"]),
        "sim": (["sim", netlist, "-o", out / "o.npz"], [out / "o.npz"]),
        "ac": (["ac", netlist, "--node", "a", "-o", out / "o.csv", "--plot", out / "a.png"],
               [out / "o.csv", out / "a.png"]),
        "modes": (["modes", netlist, "--plot", out / "m.png"], [out / "m.png"]),
        "noise": (["noise", netlist, "--node", "a", "-o", out / "n.csv"], [out / "n.csv"]),
        "grad": (["grad", netlist, "--of", "final:x(a)", "--wrt", "k0"], []),
        "export": (["export", netlist, "--spice", "-o", out / "o.cir"],
                   [out / "o.cir", out / "o.p0.cir"]),
    }
    return table[command]


@pytest.fixture
def empty_cache(tmp_path, monkeypatch) -> Path:
    """A kernel cache that must stay empty: nothing is compiled before these errors."""
    cache = tmp_path / "kernels"
    monkeypatch.setenv("SPRINGC_CACHE", str(cache))
    return cache


def _undamped(text: str) -> str:
    return text.replace("M1 a m=1 b=0.5", "M1 a m=1")


@pytest.mark.parametrize("command", POPULATION_COMMANDS)
@pytest.mark.parametrize("case", sorted(POPULATION))
def test_population_and_noise_misuse_is_located(case, command, tmp_path, empty_cache):
    lines, where, words = POPULATION[case]
    text = BASE + lines
    netlist = tmp_path / f"{case}.spr"
    netlist.write_text(_undamped(text) if case in UNDAMPED else text)
    args, written = population_args(command, netlist, tmp_path)
    code, output = run(args)
    assert code == 1, output
    assert first_line(output).startswith(f"{netlist}:{where}: error: "), output
    assert words in first_line(output), output
    assert not [p for p in written if p.exists()], output
    assert not empty_cache.exists() or not any(empty_cache.iterdir()), output


# (command, extra arguments, words of the message): refused by name before any work
OPTION_MISUSE = {
    "sim-temp-negative": ("sim", ["--temp", "-1"], "temp must be a finite temperature"),
    "sim-temp-nan": ("sim", ["--temp", "nan"], "temp must be a finite temperature"),
    "sim-temp-inf": ("sim", ["--temp", "inf"], "temp must be a finite temperature"),
    "sim-temp-no-damper": ("sim", ["--temp", "300"], "has no damper"),
    "noise-temp-negative": ("noise", ["--temp", "-1"], "temp must be a finite temperature"),
    "noise-temp-nan": ("noise", ["--temp", "nan"], "temp must be a finite temperature"),
    "noise-temp-inf": ("noise", ["--temp", "inf"], "temp must be a finite temperature"),
    "noise-temp-zero": ("noise", ["--temp", "0"], "temperature 0 K"),
    "noise-no-damper": ("noise", [], "has no damper"),
    "noise-unknown-node": ("noise", ["--node", "zz"], "unknown node 'zz'"),
    "noise-fmin-zero": ("noise", ["--fmin", "0"], "bad sweep"),
    "noise-band-reversed": ("noise", ["--fmin", "10", "--fmax", "1"], "bad sweep"),
    "noise-one-point": ("noise", ["--points", "1", "--fmin", "1", "--fmax", "10"],
                        "bad sweep"),
    "ac-fmin-zero": ("ac", ["--fmin", "0"], "bad sweep"),
}


@pytest.mark.parametrize("case", sorted(OPTION_MISUSE))
def test_noise_options_misuse_is_named(case, tmp_path, empty_cache):
    command, extra, words = OPTION_MISUSE[case]
    netlist = tmp_path / "n.spr"
    netlist.write_text(_undamped(BASE) if "no-damper" in case else BASE)
    args, written = population_args(command, netlist, tmp_path)
    if "--node" in extra:
        args = [a for a in args if a not in ("--node", "a")]
    code, output = run([*args, *extra])
    assert code == 1, output
    assert first_line(output).startswith("error: ") and words in output, output
    assert not [p for p in written if p.exists()], output
    # the netlist itself passed its checks (kept in checked/, springc.check.store): nothing
    # was compiled before the option was refused
    assert not [p for p in empty_cache.glob("*") if p.name != "checked"], output
