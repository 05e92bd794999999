"""The replay engine: a session streamed through the feature chain and the classifier.

The session is read in batches (row groups of the file, see
:func:`contactkit.schemas.session.iter_session_batches`), so memory stays bounded by
one batch however long the session is. Each batch goes through
:class:`contactkit.features.timeseries.TimeseriesChain`, whose state (observer, last
velocity) is carried from batch to batch: the numbers equal the whole-session chain.
Every ``hop_s`` seconds, once a full window is available, the scalar features of the
last ``window_s`` seconds (the window length the model was trained with), or for a
network the resampled window grid, go through the model: each prediction is stamped
with the time of the last sample it used, so it never looks ahead; the engine keeps
only the last seconds of features that such a window needs. Where the model carries
a contact detector (or one is given), every sample also goes through the event
pipeline (:mod:`contactkit.classify.events.contact_events`: detect, decide once, hold until
release), which needs no planned interaction time, and gates the per-hop output:
without a detected contact a hop's label is ``none`` (probability 1), whatever the
window classifier says (its own probabilities stay in ``pred_window_proba``), because
the window classifier was trained on contacts at a planned time and calls fast free
motion a contact. After a gap (a step over
:data:`contactkit.features.timing.RESTART_STEP_S`) the chain and the detector restart,
an open event ends before the gap, and the hops start again one window after it, as at
the start of the session. For a session with a planned time the engine also gives the offline
answer: the window found by the thesis method and the model's label for it, from the
features it streamed (:class:`contactkit.features.window_stream.WindowCollector`) and
through the same predictor as every hop (see :meth:`ReplayStream.offline`).

:meth:`ReplayStream.blocks` yields each batch's samples with their features and
predictions as a :class:`Block`; a paced replay asks for a block after every hop, so
it can sleep and log incrementally. A block also carries the contact estimates of the
events' tracks made among its samples: the stream's events keep no track (their
``contact_track`` is empty), so that memory stays bounded by a batch however long the
session is in contact.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Iterator
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from contactkit.classify.events.contact_events import NONE, ContactEvent, EventPipeline
from contactkit.classify.modelfile.model_file import ModelFile
from contactkit.errors import input_error_about
from contactkit.features.agreement import ResidualAgreement
from contactkit.features.detector import DYNAMIC_FEATURE, DetectorConfig, dynamics_detector
from contactkit.features.isolation import ContactEstimate, robot_isolator
from contactkit.features.timeseries import ChainConfig, TimeseriesChain, columns_of, expand
from contactkit.features.timing import restarts
from contactkit.features.window_stream import WindowCollector
from contactkit.features.windows import Window
from contactkit.replay.hop import DEFAULT_HOP_S
from contactkit.robots import get_robot
from contactkit.robots.dynamics import RobotChoice, override_dynamics, override_robot
from contactkit.schemas import InputError, Session
from contactkit.schemas.columns import check_time_range
from contactkit.schemas.session import SampleBatch, iter_sample_batches, read_session_meta

BATCH_ROWS = 16_384
"""Samples read and computed at a time (about 16 s at 1 kHz)."""
HISTORY_MARGIN_S = 1.0
"""Seconds of features kept before a prediction window (a network's baseline), and
either side of the offline window."""


@dataclass
class Block:
    """Samples ``[start, stop)`` (indices over the session's complete samples) just
    processed: times ``t`` [s], ``q`` [rad], ``dq`` [rad/s], ``tau`` [Nm] (n, 7), the
    residual ``r`` [Nm] (n, 7), ``force`` [N] and ``moment`` [Nm] (n, 3), their
    ``norms`` (n, 2), the ground truth where the session has it (``true_force`` [N]
    (n, 3), ``contact`` (n,)), the robot's own external-torque estimate with the
    residual's sign (``robot_estimate``, -tau_ext_hat [Nm] (n, 7), where the session
    has it), the event pipeline's per-sample ``event_label`` and ``score`` (None
    without a detector), the predictions made among these samples: ``pred_t`` [s],
    ``pred_sample``, ``pred_proba`` (m, classes) and ``pred_label``, and the contact
    estimates of the events' tracks made among them, (session sample, estimate) in
    order (``estimates``; empty without a detector or without contact isolation)."""

    start: int
    stop: int
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    r: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    norms: np.ndarray
    true_force: np.ndarray | None = None
    contact: np.ndarray | None = None
    robot_estimate: np.ndarray | None = None
    event_label: np.ndarray | None = None
    score: np.ndarray | None = None
    pred_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pred_sample: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    pred_proba: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    pred_label: list[str] = field(default_factory=list)
    estimates: list[tuple[int, ContactEstimate]] = field(default_factory=list)

    @property
    def sample(self) -> np.ndarray:
        """The session sample index of each row, (n,)."""
        return np.arange(self.start, self.stop)


@dataclass
class OfflineAnswer:
    """The thesis method's window for the whole session and the model's label for it;
    ``start_sample`` and ``end_sample`` are the session samples at the window's ends."""

    window: Window
    label: str
    probabilities: np.ndarray
    start_sample: int = 0
    end_sample: int = 0


def next_hop_after(hop: float, t: float, hop_s: float) -> float:
    """Return the first prediction time [s] on the grid ``hop + i * hop_s`` that lies
    after ``t`` [s], in one step: a gap in the time stamps (a jump of hours, or of
    1e9 s after a clock switch) is jumped over, never walked through hop by hop, and
    the result is always past ``t`` even where ``hop_s`` is below the resolution of
    ``t``."""
    if hop <= t + 1e-12:
        hop += hop_s * (math.floor((t + 1e-12 - hop) / hop_s) + 1)
    return max(hop, math.nextafter(t, math.inf))


class _HopLog:
    """A replay's per-hop predictions as growing columns: times [s], session sample
    indices, probabilities (gated) and the window classifier's own (classes each), and
    each label's index in the model's classes; 18 + 16 bytes per class a hop. The
    columns grow by doubling, so appending costs constant time a hop on average, and
    :meth:`column` gives a read-only view of the hops so far without a copy (rows are
    only ever added after it: later hops do not change it)."""

    def __init__(self, n_classes: int) -> None:
        self.size = 0
        self._columns: dict[str, np.ndarray] = {
            "t": np.zeros(0), "sample": np.zeros(0, dtype=np.int64),
            "proba": np.zeros((0, n_classes)), "window_proba": np.zeros((0, n_classes)),
            "label": np.zeros(0, dtype=np.int16)}

    def append(self, **rows: np.ndarray) -> None:
        """Add the rows of each column (the same number of rows in each)."""
        n = len(rows["t"])
        grown = self.size + n
        for name, column in self._columns.items():
            if grown > len(column):
                larger = np.empty((max(grown, 2 * len(column)), *column.shape[1:]),
                                  dtype=column.dtype)
                larger[:self.size] = column[:self.size]
                self._columns[name] = column = larger
            column[self.size:grown] = rows[name]
        self.size = grown

    def column(self, name: str) -> np.ndarray:
        """Return the hops so far of column ``name``, a read-only view."""
        view = self._columns[name][:self.size]
        view.flags.writeable = False
        return view


class ReplayStream:
    """Streams one session (a file, read batch by batch, or a :class:`Session` in
    memory) through the chunked chain, the event pipeline and the classifier.

    After (or while) iterating :meth:`blocks`: predictions ``pred_t`` [s],
    ``pred_sample``, ``pred_proba`` (read-only array views) and ``pred_label`` (a
    list), gated by the detector where there is one, the window classifier's own
    ``pred_window_proba`` (kept as growing columns: 18 + 16 bytes per class a hop), and
    with a
    detector :attr:`events`, whose ``contact_track`` stays empty: the estimates of their
    tracks come with the blocks (:attr:`Block.estimates`).
    ``detector`` overrides the model's detector settings; ``decide_after_s`` its
    decision delay [s]; ``detector`` holds the settings in use (None without one).
    ``batch_rows`` is the number of samples read and computed at a time (default
    ``BATCH_ROWS``); ``robot`` names the arm's model instead of the session's own
    (:mod:`contactkit.robots`), or is an
    :class:`~contactkit.robots.dynamics.ArmOverride` with the arm's identified dynamics:
    the chain, the detector (the file's thresholds, unless ``detector`` is given) and
    isolation then use them.
    """

    def __init__(self, session: Session | str | Path, model: ModelFile,
                 hop_s: float = DEFAULT_HOP_S, detector: DetectorConfig | None = None,
                 decide_after_s: float | None = None, batch_rows: int | None = None,
                 robot: RobotChoice = None) -> None:
        if hop_s <= 0:
            raise InputError(f"the prediction hop must be positive, got {hop_s} s")
        if isinstance(session, Session):
            self.session: Session | None = session
            self.meta, self.path = session.meta, session.path
        else:
            self.session = None
            self.path = Path(session)
            self.meta, _ = read_session_meta(self.path)
        try:
            self.meta = self.meta.with_robot(override_robot(robot))
        except InputError as err:
            raise input_error_about(err, self.path) from err
        self.model = model
        self.hop_s = hop_s
        self.batch_rows = batch_rows or BATCH_ROWS
        self._predict_proba = model.online_predictor()
        self.classes = model.classes
        self._none_proba = ((np.array(self.classes) == NONE).astype(float)
                            if NONE in self.classes else None)
        """A hop's probabilities outside a detected contact: 1 for ``none`` (None for a
        model without that class)."""
        self.transformer = model.online_transformer()
        model.check_features(list(self.transformer.get_feature_names_out()))
        timeseries, self.window_s = self.transformer.timeseries, float(self.transformer.window_s)
        chain = self.transformer.chain_config()
        dynamics = override_dynamics(robot)
        self.chain_config = ChainConfig(chain.observer, chain.wrench_frame, dynamics=dynamics)
        setup = self.chain_config.robot_setup(self.meta, self.path)
        self.names = expand(list(timeseries))
        self.channels = [c for name in self.names for c in columns_of(name)]
        self._hops = _HopLog(len(self.classes))
        # the identified model's thresholds: --dynamics', else those the session carries
        detector = detector or dynamics_detector(setup.dynamics) or model.detector_config()
        self.detector = detector = None if detector is None else detector.for_robot(
            get_robot(setup.robot))
        self.pipeline = None if detector is None else EventPipeline(
            detector, model.event_model(), decide_after_s, robot_isolator(setup),
            keep_track=False)
        self.event_samples: dict[float, int] = {}
        """Session time [s] -> sample index of every sample where an event began, was
        decided or ended, and of the first and (once the stream has ended) the last
        sample."""
        self.window_spec = self.transformer.window_spec
        planned = self.meta.planned_at_s
        self._offline = None if planned is None else \
            WindowCollector(planned, self.window_spec, HISTORY_MARGIN_S)
        self.n_samples = 0
        self.rate_hz: float | None = None
        """The sample rate [Hz] by the median step of the first batch (None while
        unknown, or for a first batch of one sample)."""
        self.planned_sample: int | None = None
        self._span: tuple[float, float] | None = None
        self.agreement = ResidualAgreement()
        """The residual's agreement with the robot's own estimate (sessions with
        ``tau_ext_hat``), accumulated as the session streams."""

    @property
    def events(self) -> list[ContactEvent]:
        """The contact events so far (the last one may still be open)."""
        return [] if self.pipeline is None else self.pipeline.finish()

    def time_span(self) -> tuple[float, float]:
        """Return the times [s] of the session's first and last sample (read once, from
        the first and last row group only)."""
        if self._span is None:
            self._span = self._read_time_span()
        return self._span

    def _read_time_span(self) -> tuple[float, float]:
        if self.session is not None:
            t = self.session.t
            return float(t[0]), float(t[-1])
        try:
            file = pq.ParquetFile(self.path)
            last = file.metadata.num_row_groups - 1
            first_t = file.read_row_group(0, columns=["t"]).column("t")
            last_t = file.read_row_group(last, columns=["t"]).column("t")
            first, last = float(first_t[0].as_py()), float(last_t[-1].as_py())
        except (pa.ArrowInvalid, OSError, IndexError, KeyError, TypeError, ValueError) as err:
            raise InputError(f"cannot read the sample times ({err})", self.path) from err
        check_time_range(first, last, self.path)
        return first, last

    def _batches(self) -> Iterator[SampleBatch]:
        source = self.session if self.session is not None else self.path
        assert source is not None  # a stream has its session or its file
        return iter_sample_batches(source, self.batch_rows)

    def blocks(self, every_hop: bool = False) -> Iterator[Block]:
        """Stream the session; yield a :class:`Block` per batch read, or with
        ``every_hop`` after every prediction (and at the end of each batch)."""
        robot = self.chain_config.robot_setup(self.meta, self.path)
        detector = [] if self.detector is None else self.detector.chain_features
        chain = TimeseriesChain(self.chain_config, robot,
                                list(dict.fromkeys([*self.names, "r", "f", "m", "fm_norm",
                                                    self.window_spec.signal, *detector])))
        self.model.check_robot(robot.robot, self.path)  # once its model is built
        history_t, history_v = np.zeros(0), np.zeros((0, len(self.channels)))
        next_hop = last_t = None
        start = 0
        planned = self.meta.planned_at_s
        for batch in self._batches():
            n = len(batch)
            t, q, dq, tau = batch.t, batch.q, batch.dq, batch.tau
            if next_hop is None:
                next_hop = t[0] + self.window_s
                steps = np.diff(t)
                self.rate_hz = 1.0 / float(np.median(steps)) if steps.size else None
                self.event_samples[float(t[0])] = 0
            gaps = restarts(t, last_t)
            last_t = float(t[-1])
            if planned is not None and self.planned_sample is None and t[-1] >= planned:
                self.planned_sample = start + int(np.searchsorted(t, planned))
            out = chain.feed(batch)
            values = np.column_stack([out[name] for name in self.names])
            buffer_t, buffer_v = np.r_[history_t, t], np.vstack([history_v, values])
            offset = len(history_t)
            if self._offline is not None:
                self._offline.add(np.arange(start, start + n), t, values,
                                  out[self.window_spec.signal])
            labels = scores = None
            estimates: list[tuple[int, ContactEstimate]] = []
            if self.pipeline is not None:
                labels, scores, estimates = self._events(t, out["r"], dq, q, start,
                                                         out.get(DYNAMIC_FEATURE))
            truth, contact = batch.f_ext, batch.contact
            estimate = None if batch.tau_ext_hat is None else -batch.tau_ext_hat
            if estimate is not None:
                self.agreement.update(t, out["r"], -estimate)
            whole = Block(start, start + n, t, q, dq, tau, out["r"], out["f"], out["m"],
                          out["fm_norm"], truth, contact, estimate, labels, scores,
                          estimates=estimates)
            hops, next_hop = hop_rows(t, gaps, next_hop, self.window_s, self.hop_s)
            predictions = self._predict(buffer_t, buffer_v, offset, start, hops, labels)
            first = 0
            if every_hop:
                for k, prediction in zip(hops, predictions, strict=True):
                    yield _part(whole, first, k + 1, [prediction])
                    first = k + 1
                predictions = []
            if first < n:
                yield _part(whole, first, n, predictions)
            keep = max(0, int(np.searchsorted(buffer_t, t[-1] - self.window_s
                                              - HISTORY_MARGIN_S)) - 1)
            history_t, history_v = buffer_t[keep:], buffer_v[keep:]
            start += n
            self.n_samples = start
        if start == 0:
            raise InputError("session has no complete samples", self.path)
        assert last_t is not None  # set by the first batch
        self.event_samples[last_t] = start - 1

    def _events(self, t: np.ndarray, r: np.ndarray, dq: np.ndarray, q: np.ndarray,
                start: int, dyn: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, ContactEstimate]]]:
        """Feed a batch (first session sample ``start``; the dynamic torque scale
        ``dyn`` [Nm] when the detector reads it) to the event pipeline in one go;
        note the samples where events begin, are decided or end. Return the per-sample
        labels and detector scores, and the contact estimates of the events' tracks
        made in the batch as (session sample, estimate)."""
        assert self.pipeline is not None  # called with a pipeline only
        found = self.pipeline.update_block(t, r, dq, q, dyn)
        estimates = []
        for k, state in found.steps:
            at, sample = float(t[k]), start + k
            released_s = None if state.released is None else state.released.release_s
            cut = released_s is not None and released_s < at
            if cut:  # by a gap: decided (if it was not) and released at the sample before it
                assert released_s is not None
                self.event_samples[released_s] = sample - 1
            if state.started is not None or (not cut and (state.decided or state.released)):
                self.event_samples[at] = sample
            if state.estimate is not None:
                estimates.append((sample, state.estimate))
        return found.labels, found.score, estimates

    def _predict(self, t: np.ndarray, values: np.ndarray, offset: int, start: int,
                 hops: list[int], labels: np.ndarray | None
                 ) -> list[tuple[float, int, np.ndarray, str]]:
        """Classify the windows ending at the batch rows ``hops`` (buffer rows ``offset``
        on, session samples ``start`` on) in one call; outside a detected contact (by
        the per-sample ``labels``, None without a detector) a hop is ``none``. Return
        (time [s], sample, probabilities, label) of each."""
        if not hops:
            return []
        rows = offset + np.asarray(hops)
        window_probas = self._predict_proba(self.transformer.online_rows(t, values, rows))
        probas = window_probas.copy()
        chosen = np.argmax(window_probas, axis=1)
        if labels is not None and self._none_proba is not None:  # gated outside contacts
            gated = labels[hops] == NONE
            probas[gated] = self._none_proba
            chosen[gated] = self.classes.index(NONE)
        at, samples = t[rows], start + np.asarray(hops, dtype=np.int64)
        self._hops.append(t=at, sample=samples, proba=probas, window_proba=window_probas,
                          label=chosen)
        names = [self.classes[i] for i in chosen.tolist()]
        return list(zip(at.tolist(), samples.tolist(), list(probas), names, strict=True))

    @property
    def pred_t(self) -> np.ndarray:
        """Times [s] of the hops predicted so far, (m,): a read-only view, which later hops
        do not change."""
        return self._hops.column("t")

    @property
    def pred_sample(self) -> np.ndarray:
        """Session sample index of each hop predicted so far, (m,); a read-only view, as
        :attr:`pred_t`."""
        return self._hops.column("sample")

    @property
    def pred_proba(self) -> np.ndarray:
        """Probabilities of each hop predicted so far (gated by the detector where there
        is one), (m, classes), columns in :attr:`classes`' order; a read-only view, as
        :attr:`pred_t`."""
        return self._hops.column("proba")

    @property
    def pred_window_proba(self) -> np.ndarray:
        """The window classifier's own probabilities of each hop, ungated, (m,
        classes); a read-only view, as :attr:`pred_t`."""
        return self._hops.column("window_proba")

    @property
    def pred_label(self) -> list[str]:
        """The label of each hop predicted so far (gated like :attr:`pred_proba`), a new
        list at each read."""
        return [self.classes[i] for i in self._hops.column("label").tolist()]

    def run(self) -> ReplayStream:
        """Process the whole session at once; return self."""
        for _ in self.blocks():
            pass
        return self

    def offline(self) -> OfflineAnswer | None:
        """Return the thesis method's window and the model's label for it (None for a
        session without a planned interaction time), from the features the stream
        computed (the session is streamed first if it has not been), through the same
        predictor as every hop. Raises InputError when the window holds too few
        samples."""
        if self._offline is None:
            return None
        if self.n_samples == 0:
            self.run()
        result = self._offline.result()
        assert result is not None  # the session has samples (run() raises otherwise)
        window, sample, t, values = result
        row = self.transformer.window_row(t, values, window, self.path)
        proba = self._predict_proba(row[None, ...])[0]
        last = len(t) - 1
        k0 = sample[min(int(np.searchsorted(t, window.start_s)), last)]
        k1 = sample[min(int(np.searchsorted(t, window.end_s)), last)]
        return OfflineAnswer(window, self.classes[int(np.argmax(proba))], proba, int(k0),
                             int(k1))


def hop_rows(t: np.ndarray, gaps: np.ndarray, next_hop: float, window_s: float,
             hop_s: float) -> tuple[list[int], float]:
    """Return the rows of a batch (times ``t`` [s]) at which a prediction is due, the first
    at or after ``next_hop`` [s] and then every ``hop_s`` (:func:`next_hop_after`), the
    grid restarted ``window_s`` after each gap (rows ``gaps``), and the next hop time
    after the batch. Each hop is found by a search, so a gap is jumped over at once;
    the search runs on the times as Python floats (``t`` increases strictly: a session's
    times do), a fraction of a NumPy search's cost per hop."""
    times = t.tolist()
    hops, row, n = [], 0, len(times)
    pending = [int(g) for g in gaps]
    while row < n:
        k = bisect_left(times, next_hop - 1e-12, row)
        if pending and pending[0] <= k:  # a window after a gap starts after it
            row = pending.pop(0)
            next_hop = times[row] + window_s
            continue
        if k >= n:
            break
        hops.append(k)
        next_hop = next_hop_after(next_hop, times[k], hop_s)
        row = k + 1
    return hops, next_hop


def _part(block: Block, first: int, stop: int,
          predictions: list[tuple[float, int, np.ndarray, str]]) -> Block:
    """Return rows ``[first, stop)`` of a batch's block with the given predictions."""
    s = slice(first, stop)

    def rows(x: np.ndarray | None) -> np.ndarray | None:
        return None if x is None else x[s]

    lo, hi = (bisect_left(block.estimates, block.start + k, key=itemgetter(0))
              for k in (first, stop))
    part = Block(block.start + first, block.start + stop, block.t[s], block.q[s],
                 block.dq[s], block.tau[s], block.r[s], block.force[s], block.moment[s],
                 block.norms[s], rows(block.true_force), rows(block.contact),
                 rows(block.robot_estimate), rows(block.event_label), rows(block.score),
                 estimates=block.estimates[lo:hi])
    if predictions:
        part.pred_t = np.array([p[0] for p in predictions])
        part.pred_sample = np.array([p[1] for p in predictions], dtype=np.int64)
        part.pred_proba = np.array([p[2] for p in predictions])
        part.pred_label = [p[3] for p in predictions]
    return part
