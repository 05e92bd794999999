"""The default model replay uses when no ``--model`` is given.

Recipe (one command: ``replay --build-default-model``; it also runs by itself, with
a progress bar, the first time replay needs the model):

1. ``recorder simulate CACHE/default-model/static --preset default-static --seed 0``
   and ``... dynamic --preset default-dynamic --seed 0`` (152 sessions at 500 Hz);
2. ``classify train`` on both: whole-arm SVM (C = 100, Platt-calibrated) on the range
   and Hjorth mobility and complexity of joint velocity, torque and observer residual
   in a 0.5 s window at the planned time, seed 0 (the per-hop classifier);
3. ``classify calibrate`` on the same sessions' no-contact stretches (margin 1.5):
   the contact detector;
4. the per-event intent classifier (:mod:`contactkit.classify.event_training`):
   SVM (C = 10) on the events the detector finds in those sessions, decided 0.15 s
   after onset, from residual-only event features.

Simulated data only. Where the simulator offers them, the presets with realistic
free motion (``free-motion``, ``mixed-motion``) replace the default ones.

Everything is seeded, so the same package version always builds the same model.
It is cached under the contactkit cache directory ($CONTACTKIT_CACHE or
~/.cache/contactkit), keyed by the recipe; nothing is downloaded.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

from contactkit.classify.calibrate import calibrate_sessions
from contactkit.classify.data import load_features
from contactkit.classify.event_training import fit_event_model, load_session_events
from contactkit.classify.events import DEFAULT_DECIDE_AFTER_S
from contactkit.classify.modelfile import save_model
from contactkit.classify.models import make_model
from contactkit.features.detector import MIN_NOISE
from contactkit.features.extract import SessionFeatures
from contactkit.recorder.dataset import PRESETS, simulate_dataset
from contactkit.schemas.dataset import session_files
from contactkit.util.cache import cache_dir

MOTION_PRESETS = ["free-motion", "mixed-motion"]
RECIPE = {
    "presets": (MOTION_PRESETS if all(p in PRESETS for p in MOTION_PRESETS)
                else ["default-static", "default-dynamic"]),
    "seed": 0,
    "model": "svm",
    "C": 100.0,
    "features": {"timeseries": ["dq", "tau", "r"],
                 "scalars": ["range", "hjorth_mob", "hjorth_comp"],
                 "window": "planned", "window_s": 0.5},
    "detector": {"margin": 1.5, "min_noise": MIN_NOISE},
    "events": {"decide_after_s": DEFAULT_DECIDE_AFTER_S, "C": 10.0},
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
    extractor = SessionFeatures(**RECIPE["features"])
    data = load_features(sources, extractor, workers,
                         None if progress is None else (lambda d, t: progress("features", d, t)))
    estimator = make_model(RECIPE["model"], data.names, RECIPE["seed"], RECIPE["C"])
    estimator.fit(data.X, data.labels())
    paths = [p for directory in sources for p in session_files(directory)]
    detector = calibrate_sessions(paths, margin=RECIPE["detector"]["margin"], workers=workers,
                                  progress=None if progress is None else
                                  (lambda d, t: progress("detector", d, t)))
    delay = RECIPE["events"]["decide_after_s"]
    events = load_session_events(paths, detector, [delay], workers,
                                 None if progress is None else
                                 (lambda d, t: progress("events", d, t)))[delay]
    event_model = fit_event_model(events, delay, RECIPE["events"]["C"], RECIPE["seed"])
    return save_model(path, estimator, extractor=extractor, feature_names=data.names,
                      classes=[str(c) for c in estimator.classes_], kind=RECIPE["model"],
                      scheme="full", fingerprint=data.fingerprint(),
                      training={"recipe": RECIPE, "sessions": len(data)}, overwrite=True,
                      detector=detector.to_dict(),
                      events=(event_model.estimator, event_model.meta()))
