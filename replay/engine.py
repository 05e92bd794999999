"""The replay engine: a session fed through the streaming chain and the classifier.

Samples go one at a time through :class:`contactkit.features.timeseries.OnlineChain` (as on a
live robot). Every ``hop_s`` seconds, once a full window is available, the scalar
features of the last ``window_s`` seconds (the window length the model was
trained with), or for a network the resampled window grid, go through the model:
each prediction is stamped with the time of the last sample it used, so it never
looks ahead. Where the model carries a contact detector (or one is given), every
sample also goes through the event pipeline (:mod:`contactkit.classify.events`:
detect, decide once, hold until release), which needs no planned interaction time,
and gates the per-hop output: without a detected contact a hop's label is ``none``
(probability 1), whatever the window classifier says (its own probabilities stay in
``pred_window_proba``), because the window classifier was trained on contacts at a
planned time and calls fast free motion a contact.
For a session with a planned time the engine also computes the offline answer:
the window found by the thesis method and the model's label for it.

:meth:`ReplayStream.blocks` yields after every hop, so a paced replay can sleep and
log incrementally; a ``--rate max`` replay consumes the same blocks at once.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from contactkit.classify.events import NONE, ContactEvent, EventPipeline
from contactkit.classify.modelfile import ModelFile
from contactkit.features.detector import DetectorConfig
from contactkit.features.timeseries import ChainConfig, OnlineChain, columns_of, expand
from contactkit.features.windows import Window
from contactkit.schemas import InputError, Session

DEFAULT_HOP_S = 0.02
ROBOT_VIEW_HZ = 60.0


@dataclass
class Block:
    """Samples [start, stop) just processed and the predictions made among them."""

    start: int
    stop: int
    predictions: range


@dataclass
class OfflineAnswer:
    """The thesis method's window for the whole session and the model's label for it."""

    window: Window
    label: str
    probabilities: np.ndarray


class ReplayStream:
    """Runs one session through the streaming chain and the classifier.

    Per-sample outputs (filled as the stream advances): ``r`` (N, 7) [Nm], ``force``
    and ``moment`` (N, 3) [N, Nm], ``norms`` (N, 2), ``ee_position`` (N, 3) [m].
    Predictions: ``pred_t`` [s], ``pred_sample``, ``pred_proba`` (M, classes) and
    ``pred_label``, gated by the detector where there is one, and the window
    classifier's own ``pred_window_proba``. Events (with a detector): ``event_label``
    (N,) the pipeline's label per sample, ``score`` (N,) the detector score, and :attr:`events`.
    ``detector`` overrides the model's detector settings; ``decide_after_s`` its
    decision delay [s]; ``detector`` holds the settings in use (None without one).
    """

    def __init__(self, session: Session, model: ModelFile, hop_s: float = DEFAULT_HOP_S,
                 detector: DetectorConfig | None = None,
                 decide_after_s: float | None = None) -> None:
        if hop_s <= 0:
            raise InputError(f"the prediction hop must be positive, got {hop_s} s")
        self.session = session = session.complete()
        self.model = model
        self.hop_s = hop_s
        self._predict_proba = model.online_predictor()
        self.classes = model.classes
        self.transformer = model.transformer()
        model.check_features(list(self.transformer.get_feature_names_out()))
        timeseries, self.window_s = self.transformer.timeseries, float(self.transformer.window_s)
        chain = self.transformer.chain_config()
        self.observer, self.wrench_frame = chain.observer, chain.wrench_frame
        self.names = expand(list(timeseries))
        self.channels = [c for name in self.names for c in columns_of(name)]
        n = session.n_samples
        self.t = session.t
        steps = np.diff(self.t)
        rate = 1.0 / float(np.median(steps)) if steps.size else ROBOT_VIEW_HZ
        self.robot_stride = max(1, round(rate / ROBOT_VIEW_HZ))
        self.r = np.zeros((n, 7))
        self.force = np.zeros((n, 3))
        self.moment = np.zeros((n, 3))
        self.norms = np.zeros((n, 2))
        self.ee_position = np.zeros((n, 3))
        self._values = np.zeros((n, len(self.channels)))
        self.pred_t: list[float] = []
        self.pred_sample: list[int] = []
        self.pred_proba: list[np.ndarray] = []
        self.pred_window_proba: list[np.ndarray] = []
        self.pred_label: list[str] = []
        self.detector = detector = detector or model.detector_config()
        self.pipeline = None if detector is None else EventPipeline(
            detector, model.event_model(), decide_after_s)
        self.event_label = np.full(n, "none", dtype=object)
        self.score = np.zeros(n)

    @property
    def events(self) -> list[ContactEvent]:
        """The contact events so far (the last one may still be open)."""
        return [] if self.pipeline is None else self.pipeline.finish()

    def _predict(self, k: int) -> None:
        row = self.transformer.online_row(self.t, self._values, k)
        window_proba = proba = self._predict_proba(row[None, ...])[0]
        if self.pipeline is not None and self.event_label[k] == NONE and NONE in self.classes:
            proba = (np.array(self.classes) == NONE).astype(float)
        self.pred_t.append(float(self.t[k]))
        self.pred_sample.append(k)
        self.pred_proba.append(proba)
        self.pred_window_proba.append(window_proba)
        self.pred_label.append(self.classes[int(np.argmax(proba))])

    def blocks(self) -> Iterator[Block]:
        """Advance sample by sample; yield a :class:`Block` after every hop (and at the end)."""
        session = self.session
        chain = OnlineChain(ChainConfig(self.observer, self.wrench_frame),
                            session.meta.with_hand)
        ee = chain.model.end_effector
        q, dq, tau = session.q, session.dq, session.tau
        next_hop = self.t[0] + self.window_s
        start = 0
        for k in range(session.n_samples):
            out = chain.update(self.t[k], q[k], dq[k], tau[k])
            self.r[k], self.force[k], self.moment[k] = out["r"], out["f"], out["m"]
            self.norms[k] = out["fm_norm"]
            self.ee_position[k] = chain.model.frame_placement(q[k], ee).translation
            self._values[k] = np.concatenate([out[name] for name in self.names])
            if self.pipeline is not None:
                state = self.pipeline.update(self.t[k], out["r"], dq[k])
                self.event_label[k], self.score[k] = state.label, state.score
            if self.t[k] >= next_hop - 1e-12:
                before = len(self.pred_t)
                self._predict(k)
                while next_hop <= self.t[k] + 1e-12:
                    next_hop += self.hop_s
                yield Block(start, k + 1, range(before, len(self.pred_t)))
                start = k + 1
        if start < session.n_samples:
            yield Block(start, session.n_samples, range(len(self.pred_t), len(self.pred_t)))

    def run(self) -> ReplayStream:
        """Process the whole session at once; return self."""
        for _ in self.blocks():
            pass
        return self

    def offline(self) -> OfflineAnswer | None:
        """Return the thesis method's window and the model's label for it (None for a
        session without a planned interaction time)."""
        if self.session.meta.planned_at_s is None:
            return None
        values, names, window = self.transformer.session_row(self.session)
        self.model.check_features(names, self.session.path)
        proba = self.model.estimator.predict_proba(values[None, ...])[0]
        return OfflineAnswer(window, self.classes[int(np.argmax(proba))], proba)
