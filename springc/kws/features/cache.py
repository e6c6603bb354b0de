"""On-disk cache of feature matrices, one `.npz` per (data set fingerprint, split, feature
settings, augmentation seed) under `$SPRINGC_CACHE` or `~/.cache/springc/features`.

Entries are written atomically (temp file, then rename), so an interrupted run never leaves
a truncated entry; an unreadable entry is ignored and recomputed."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np


def cache_root() -> Path:
    """The cache folder: $SPRINGC_CACHE if set, else ~/.cache/springc/features."""
    env = os.environ.get("SPRINGC_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "springc" / "features"


def fingerprint(clips: list) -> str:
    """A hash of the clips (key, file size, modification time): changes when any file of the
    split is added, removed or rewritten."""
    h = hashlib.sha256()
    for clip in clips:
        st = Path(clip.path).stat()
        h.update(f"{clip.key()}|{clip.label}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:20]


def entry_path(fp: str, split: str, settings: dict, seed: int | None) -> Path:
    """Where the features for this (fingerprint, split, settings, seed) live."""
    key = json.dumps({"fp": fp, "split": split, "settings": settings, "seed": seed},
                     sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:24]
    return cache_root() / f"{split}-{digest}.npz"


def load(path: Path, rows: int) -> np.ndarray | None:
    """The cached matrix, or None when absent, unreadable or of the wrong length."""
    try:
        with np.load(path) as data:
            x = data["features"]
    except (OSError, KeyError, ValueError):
        return None
    return x if x.shape[0] == rows else None


def save(path: Path, features: np.ndarray) -> None:
    """Store `features` atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, features=features)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
