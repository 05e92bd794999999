"""Replay cost of Rerun logging, .rrd size, and paced-replay lag.

For a 10 s simulated session at 1 kHz, replayed with a contact detector (so the event,
threshold and isolated-contact lanes are logged too), prints: the feature chain alone on
the session (the chain's baseline), the replay's computation without logging (chain,
classifier, event pipeline), the time to log that replay to an .rrd file exactly as the
CLI does (timed on its own: the difference of two noisy totals is not reliable) and its
ratio to the computation, a whole replay to an .rrd (what ``replay --viewer none``
runs after start-up) against the chain alone and against the computation without
logging (what logging adds to the replay a user waits for, the file's atomic write
and Rerun's encoding thread, which shares the cores with the computation, included;
the two are timed in turn, five times each, and the best of each taken),
what Rerun alone takes to send and write the lanes logged at every sample (the floor
of logging at full rate, no Python around the calls), logging thinned to 250 and
100 Hz (``--log-rate``), the file size per second of session, and for a paced replay
at --rate 1 the lag between wall clock and session time at each hop (median, max). Every baseline is
measured in the same run; each time is the best of 5.

    .venv/bin/python benchmarks/bench_replay.py
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import rerun as rr

from contactkit.classify.data import load_features
from contactkit.classify.kinds.registry import get_kind, make_estimator
from contactkit.classify.modelfile.model_file import load_model, save_model
from contactkit.cli.default_model import RECIPE
from contactkit.features.detector import DetectorConfig
from contactkit.features.extract import SessionFeatures
from contactkit.features.timeseries import TimeseriesChain
from contactkit.recorder.sim.dataset import simulate_specs
from contactkit.recorder.sim.simulator import SimConfig, plan_session
from contactkit.recorder.sources.sim import SIM_COLUMNS, SimSource
from contactkit.replay.engine import Block, ReplayStream
from contactkit.replay.recording import BlockLogger, log_results, log_static, new_recording
from contactkit.replay.session_replay import replay_session
from contactkit.schemas import read_session, write_session
from contactkit.viewer import layout


def setup(tmp: Path) -> tuple[Path, Path]:
    """A 10 s session at 1 kHz and a model with the default model's features, trained on
    32 small sessions."""
    specs = [plan_session(seed=100 * r + 10 * p + a, condition="static", action=action,
                          pose=pose, duration_s=4.0, planned_at_s=2.5)
             for r in range(2) for p, pose in enumerate("ABCD")
             for a, action in enumerate(("none", "bump", "adjust", "shove"))]
    (tmp / "train").mkdir()
    simulate_specs(specs, SimConfig(rate_hz=250.0), tmp / "train")
    features = RECIPE["features"]  # the default model's input: range and Hjorth parameters
    extractor = SessionFeatures(timeseries=tuple(features["timeseries"]), window="planned",
                                scalars=tuple(features["scalars"]))
    data = load_features([tmp / "train"], extractor, workers=2, cache=False)
    estimator = make_estimator("svm", data.names).fit(data.X, data.labels())
    model = save_model(tmp / "m.skops", estimator, transformer=extractor,
                       feature_names=data.names, classes=list(estimator.classes_),
                       kind=get_kind("svm"), scheme="full",
                       fingerprint="", training={})
    return simulated_session(tmp / "s.parquet", DURATION_S), model


def simulated_session(path: Path, duration_s: float) -> Path:
    """Write a simulated session of ``duration_s`` [s] at 1 kHz, a shove on link 6 at
    5 s, to ``path``; return it."""
    spec = plan_session(seed=9, condition="static", action="shove", pose="B", link=6,
                        duration_s=duration_s, planned_at_s=5.0)
    source = SimSource(spec, SimConfig(rate_hz=1000.0), chunk=500)
    chunks = list(source.stream())
    columns = {k: np.concatenate([c[k] for c in chunks]) for k in SIM_COLUMNS}
    return write_session(path, columns, source.session_meta())


DURATION_S = 10.0
LONG_S = 60.0
"""A second, longer session [s]: logging's cost per second of session, beyond what a
recording costs however short (blueprint, robot model, closing the file)."""
REPEATS = 5
"""Runs of each timing; the best is reported."""
THINNED_HZ = (250.0, 100.0)
"""Log rates [Hz] of the thinned-logging rows (``replay --log-rate``)."""
DETECTOR = DetectorConfig()


def chain_alone(session_path: Path, model_path: Path) -> float:
    """Read the session and run the model's feature chain on it; return wall time [s]."""
    model = load_model(model_path)
    names = ReplayStream(session_path, model).names
    start = time.perf_counter()
    session = read_session(session_path)
    chain = TimeseriesChain.for_session(session.meta, model.transformer().chain_config())
    chain.compute(session.t, session.q, session.dq, session.tau, names)
    return time.perf_counter() - start


def whole_replay(session_path: Path, model_path: Path, rrd: Path) -> float:
    """Replay the session into an .rrd file as ``replay --viewer none`` does (after
    loading the model); return wall time [s]."""
    model = load_model(model_path)
    start = time.perf_counter()
    replay_session(session_path, model, save=rrd, detector=DETECTOR, overwrite=True)
    return time.perf_counter() - start


def compute(session_path: Path, model_path: Path
            ) -> tuple[ReplayStream, list[Block], object, float]:
    """Run one --rate max replay without logging (after loading the model, as the other
    timings); return it, its blocks and its wall time [s]."""
    model = load_model(model_path)
    start = time.perf_counter()
    stream = ReplayStream(session_path, model, detector=DETECTOR)
    blocks = list(stream.blocks())
    answer = stream.offline()
    return stream, blocks, answer, time.perf_counter() - start


def log_to_file(stream: ReplayStream, blocks: list[Block], answer, rrd: Path,
                log_rate_hz: float | None = None) -> float:
    """Log a computed replay to an .rrd file exactly as the CLI does (with ``--log-rate
    log_rate_hz``; None: every sample); return wall time [s]."""
    start = time.perf_counter()
    rec = new_recording("bench", "bench")
    rec.save(rrd, default_blueprint=layout.replay_blueprint())
    logger = BlockLogger(rec, log_static(rec, stream), stream, log_rate_hz)
    for block in blocks:
        logger.log(block)
    logger.finish()
    log_results(rec, stream, answer)
    rec.flush()
    rec.disconnect()
    return time.perf_counter() - start


def full_rate_lanes(block: Block) -> list[tuple[str, np.ndarray]]:
    """Return (entity path, values) of each lane the replay logs at every sample."""
    return [(layout.Q, block.q), (layout.DQ, block.dq), (layout.TAU, block.tau),
            (layout.RESIDUAL, block.r), (layout.FORCE, block.force),
            (layout.MOMENT, block.moment), (layout.FORCE_NORM, block.norms[:, :1]),
            (layout.MOMENT_NORM, block.norms[:, 1:])]


def dense_lanes_alone(blocks: list[Block], rrd: Path) -> float:
    """Send only the replay's full-rate lanes (joints, residual, force, moment and
    their norms), each as one column with the time and sample timelines, to an .rrd
    file and close it: no blueprint, styles, robot, events or predictions, no Python
    around the calls. What Rerun itself takes for the bulk of the data; return wall
    time [s]."""
    start = time.perf_counter()
    rec = rr.RecordingStream("bench-floor", recording_id="bench-floor")
    rec.save(rrd)
    for block in blocks:
        index = layout.time_columns(block.t, block.sample)
        for path, values in full_rate_lanes(block):
            rec.send_columns(path, indexes=index, columns=rr.Scalars.columns(scalars=values))
    rec.disconnect()
    return time.perf_counter() - start


def paced_lag(session_path: Path, model_path: Path, rrd: Path) -> np.ndarray:
    """Lag [s] of wall clock behind session time at every hop of a --rate 1 replay."""
    stream = ReplayStream(session_path, load_model(model_path), detector=DETECTOR)
    rec = new_recording("bench-paced", "bench-paced")
    rec.save(rrd)
    logger = BlockLogger(rec, log_static(rec, stream), stream)
    lags = []
    started = time.monotonic()
    t0, _ = stream.time_span()
    for block in stream.blocks(every_hop=True):
        logger.log(block)
        due = started + block.t[-1] - t0
        now = time.monotonic()
        lags.append(max(0.0, now - due))
        if due > now:
            time.sleep(due - now)
    logger.finish()
    rec.flush()
    rec.disconnect()
    return np.array(lags)


def main() -> None:
    """Measure and print the table."""
    with tempfile.TemporaryDirectory() as tmp:
        session, model = setup(Path(tmp))
        chain = min(chain_alone(session, model) for _ in range(REPEATS))
        runs, wholes = [], []
        for _ in range(REPEATS):  # interleaved, so that both see the machine alike
            runs.append(compute(session, model))
            wholes.append(whole_replay(session, model, Path(tmp) / "whole.rrd"))
        whole = min(wholes)
        bare = min(r[3] for r in runs)
        stream, blocks, answer, _ = runs[-1]
        logging = min(log_to_file(stream, blocks, answer, Path(tmp) / f"r{i}.rrd")
                      for i in range(REPEATS))
        size = (Path(tmp) / "r0.rrd").stat().st_size
        floor = min(dense_lanes_alone(blocks, Path(tmp) / f"d{i}.rrd") for i in range(REPEATS))
        thinned = {rate: min(log_to_file(stream, blocks, answer, Path(tmp) / f"t{i}.rrd", rate)
                             for i in range(REPEATS)) for rate in THINNED_HZ}
        lags = paced_lag(session, model, Path(tmp) / "paced.rrd")
        long_session = simulated_session(Path(tmp) / "long.parquet", LONG_S)
        long_bare, long_log = [], {None: [], THINNED_HZ[0]: []}
        for i in range(3):
            long_stream, long_blocks, long_answer, seconds = compute(long_session, model)
            long_bare.append(seconds)
            for rate, times in long_log.items():
                times.append(log_to_file(long_stream, long_blocks, long_answer,
                                         Path(tmp) / f"long{i}.rrd", rate))
            del long_stream, long_blocks
    events = len(stream.events)
    print(f"replay of a {DURATION_S:g} s session at 1 kHz ({stream.n_samples} samples), "
          f"--rate max, with a contact detector ({events} contact events)")
    print(f"  feature chain alone (baseline): {chain:.3f} s  ({DURATION_S / chain:.1f}x real "
          "time)")
    print(f"  replay without logging:         {bare:.3f} s  ({DURATION_S / bare:.1f}x real "
          f"time, {bare / chain:.2f}x the chain)")
    print(f"  Rerun logging of it:            {logging:.3f} s  (+{100 * logging / bare:.1f} % "
          "of the replay without logging)")
    lanes = len(full_rate_lanes(blocks[0]))
    print(f"  of which Rerun alone, for the full-rate lanes: {floor:.3f} s  "
          f"(+{100 * floor / bare:.1f} %: sending the {lanes} lanes as columns and "
          "writing them, nothing else)")
    for rate, seconds in thinned.items():
        print(f"  logging with --log-rate {rate:g}:    {seconds:.3f} s  "
              f"(+{100 * seconds / bare:.1f} % of the replay without logging)")
    print(f"  whole replay to an .rrd:        {whole:.3f} s  ({DURATION_S / whole:.1f}x real "
          f"time, {whole / chain:.2f}x the chain; +{100 * (whole - bare) / bare:.1f} % of the "
          "replay without logging)")
    print(f"  .rrd size:                      {size / 1e6:.2f} MB  "
          f"({size / 1e6 / DURATION_S:.3f} MB per second of session)")
    bare_rate = (min(long_bare) - bare) / (LONG_S - DURATION_S)
    print(f"per second of session, from the {DURATION_S:g} s session to a {LONG_S:g} s one "
          f"(best of 3): replay without logging {1e3 * bare_rate:.2f} ms")
    for rate, times in long_log.items():
        short = logging if rate is None else thinned[rate]
        log_rate = (min(times) - short) / (LONG_S - DURATION_S)
        what = "every sample" if rate is None else f"--log-rate {rate:g}"
        once = short - log_rate * DURATION_S
        print(f"  logging, {what}: {1e3 * log_rate:.2f} ms (+{100 * log_rate / bare_rate:.1f} % "
              f"of the replay without logging), and {1e3 * once:.1f} ms once per recording")
    print(f"paced replay at --rate 1: lag behind session time median "
          f"{1e3 * np.median(lags):.2f} ms, max {1e3 * lags.max():.2f} ms over {len(lags)} hops")


if __name__ == "__main__":
    main()
