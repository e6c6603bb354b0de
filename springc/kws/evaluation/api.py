"""A trained keyword-spotting model from Python (`springc.kws.load_model`): classify sound
files and evaluate test splits as `springc classify` and `springc eval` do."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from springc.kws.evaluation.classify import classify
from springc.kws.evaluation.evaluate import evaluate
from springc.kws.training.model import TrainedModel, load_model as read_model


def load_model(folder: str | Path) -> Model:
    """The model folder `springc train -o FOLDER` wrote; a `DataError` naming the file for
    anything missing or inconsistent."""
    return Model(read_model(Path(folder)))


@dataclass
class Model:
    """A trained model: its `settings` (settings.json) and the classes it tells apart."""

    trained: TrainedModel

    @property
    def folder(self) -> Path:
        return self.trained.folder

    @property
    def settings(self) -> dict:
        return self.trained.settings

    @property
    def classes(self) -> list[str]:
        """Every class a decision can name, in the order the model lists them."""
        return list(dict.fromkeys(c for classes, _ in self.trained.models for c in classes))

    def classify(self, files: Sequence[str | Path], *, jobs: int = 0) -> list[dict]:
        """Per sound file (folders: their sound files) `{"file", "label", "scores"}`, the
        predicted label and every class's decision value, as `springc classify --json`."""
        return classify(self.folder, [Path(f) for f in files], jobs=jobs)

    def evaluate(self, data: str | Path | None = None, *, protocol: str | None = None,
                 jobs: int = 0, use_cache: bool = True) -> dict:
        """Accuracy, per-class counts and (mass-spring) the network's figures on the test
        split of `data` (default: the data set the model was trained on), as `springc eval
        --json`."""
        return evaluate(self.folder, Path(data) if data else None, jobs=jobs,
                        use_cache=use_cache, protocol=protocol)
