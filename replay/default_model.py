"""The default model replay uses when no ``--model`` is given.

Recipe (one command: ``replay --build-default-model``; it also runs by itself, with
a progress bar, the first time replay needs the model):

1. ``recorder simulate CACHE/default-model/static --preset default-static --seed 0``
   and ``... dynamic --preset default-dynamic --seed 0`` (152 sessions at 500 Hz);
2. ``classify train`` on both: whole-arm SVM (C = 100, Platt-calibrated) on the range
   and Hjorth mobility and complexity of joint velocity, torque and observer residual
   in a 0.5 s window at the planned time, seed 0.

Everything is seeded, so the same package version always builds the same model.
It is cached under the contactkit cache directory ($CONTACTKIT_CACHE or
~/.cache/contactkit), keyed by the recipe; nothing is downloaded.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

from contactkit.classify.kind import ModelOptions
from contactkit.classify.training import train
from contactkit.recorder.dataset import simulate_dataset
from contactkit.util.cache import cache_dir

RECIPE = {
    "presets": ["default-static", "default-dynamic"],
    "seed": 0,
    "model": "svm",
    "C": 100.0,
    "features": {"timeseries": ["dq", "tau", "r"],
                 "scalars": ["range", "hjorth_mob", "hjorth_comp"],
                 "window": "planned", "window_s": 0.5},
}
Progress = Callable[[str, int, int], None]


def recipe_dir() -> Path:
    """Return the cache directory of the current recipe."""
    key = hashlib.sha256(json.dumps(RECIPE, sort_keys=True).encode()).hexdigest()[:12]
    return cache_dir() / "default-model" / key


def default_model_path() -> Path:
    """Return where the default model file lives (it may not exist yet)."""
    return recipe_dir() / "model.skops"


def build_default_model(workers: int = 2, progress: Progress | None = None,
                        rebuild: bool = False) -> Path:
    """Simulate the recipe's data, train the model, cache it; return its path."""
    path = default_model_path()
    if path.exists() and not rebuild:
        return path
    sources = []
    for preset in RECIPE["presets"]:
        directory = recipe_dir() / preset
        simulate_dataset(directory, preset, None, RECIPE["seed"], workers,
                         progress=None if progress is None else
                         (lambda d, t, preset=preset: progress(f"simulating {preset}", d, t)))
        sources.append(directory)
    features = RECIPE["features"]
    options = ModelOptions(kind=RECIPE["model"], timeseries=tuple(features["timeseries"]),
                           scalars=tuple(features["scalars"]), window=features["window"],
                           window_s=features["window_s"], c=RECIPE["C"], seed=RECIPE["seed"])
    return train(sources, path, options, workers=workers, overwrite=True,
                 progress=progress).path
