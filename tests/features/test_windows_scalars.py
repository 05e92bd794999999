"""Windows (Appendix A) and scalar features (Table 3.4)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from contactkit.features import window_features
from contactkit.features.extract import SessionFeatures
from contactkit.features.scalars import (
    SCALARS,
    fft_magnitudes,
    hjorth_complexity,
    hjorth_mobility,
    scalar_features,
)
from contactkit.features.sliding import window_moments
from contactkit.features.windows import (
    CALIBRATIONS,
    METHODS,
    WindowSearch,
    WindowSpec,
    find_window,
)
from contactkit.schemas import InputError, read_session
from tests.conftest import make_session


def test_fixed_and_planned_windows() -> None:
    t = np.arange(0, 10, 0.001)
    w = find_window(t, 5.0, WindowSpec("fixed", 0.5, shift_s=0.1))
    assert (w.start_s, w.end_s, w.found) == (pytest.approx(4.85), pytest.approx(5.35), False)
    assert w.mask(t).sum() == pytest.approx(500, abs=1)
    p = find_window(t, 5.0, WindowSpec("planned", 0.3))
    assert (p.start_s, p.end_s) == (5.0, pytest.approx(5.3))


@pytest.mark.parametrize("method", ["difference", "change"])
@pytest.mark.parametrize("calibration", ["pre-contact", "thesis"])
def test_detection_finds_a_shove_just_after_it_starts(tmp_path, method, calibration) -> None:
    session = read_session(make_session(tmp_path, seed=8, action="shove", link=7,
                                        duration_s=8.0, planned_at_s=5.0, rate_hz=1000.0))
    onset = session.t[session.column("contact")][0]
    window = find_window(session.t, 5.0, WindowSpec(method, calibration=calibration),
                         session.tau)
    assert window.found
    assert onset - 0.01 <= window.onset_s <= onset + 0.2


def test_detection_falls_back_to_planned_time_without_contact(tmp_path) -> None:
    session = read_session(make_session(tmp_path, seed=8, action="none", duration_s=8.0,
                                        planned_at_s=5.0, rate_hz=1000.0))
    window = find_window(session.t, 5.0, WindowSpec("difference"), session.tau)
    assert not window.found and window.start_s == 5.0 and window.onset_s is None


def test_bad_window_spec() -> None:
    with pytest.raises(InputError, match="unknown window method"):
        WindowSpec("magic")
    with pytest.raises(InputError, match="must be positive"):
        WindowSpec("fixed", 0.0)


def test_scalars_on_known_signals() -> None:
    t = np.arange(400) / 1000.0
    x = np.column_stack([np.sin(2 * np.pi * 10 * t), t**2, np.full(400, 3.0)])
    values, names = scalar_features(x, ["mean", "variance", "range", "delta", "skew", "energy"],
                                    ["a", "b", "c"])
    table = dict(zip(names, values, strict=True))
    assert table["range(b)"] == pytest.approx(t[-1] ** 2)
    assert table["delta(b)"] == pytest.approx(t[-1] ** 2)
    assert table["variance(c)"] == 0 and table["skew(c)"] == 0
    assert table["skew(b)"] == pytest.approx(scipy.stats.skew(x[:, 1]))
    assert table["energy(a)"] == pytest.approx((x[:, 0] ** 2).sum())
    assert table["mean(a)"] == pytest.approx(0, abs=1e-12)
    mobility = hjorth_mobility(x[:, :1])[0]
    assert mobility == pytest.approx(2 * np.sin(np.pi * 10 / 1000), rel=1e-2)
    assert hjorth_complexity(x[:, :1])[0] == pytest.approx(1.0, abs=0.02)
    mags = fft_magnitudes(x, 3)
    assert np.allclose(mags, np.abs(np.fft.fft(x, axis=0))[:3].T)
    _, fft_names = scalar_features(x, ["fft"], ["a", "b", "c"])
    assert fft_names[:4] == ["fft0(a)", "fft0(b)", "fft0(c)", "fft1(a)"]


def test_window_search_over_chunks_equals_find_window() -> None:
    rng = np.random.default_rng(0)
    for _ in range(60):
        rows = int(rng.integers(5, 3000))
        t = np.arange(rows) / float(rng.choice([200, 500, 1000]))
        values = 0.1 * rng.standard_normal((rows, 7))
        start = int(rng.integers(0, rows))
        values[start:start + int(rng.integers(1, 200))] += rng.uniform(0, 2)
        planned = float(rng.uniform(0, t[-1] + 1))
        for method in METHODS:
            for calibration in CALIBRATIONS:
                spec = WindowSpec(method, float(rng.choice([0.2, 0.5, 1.5])),
                                  calibration=calibration)
                size = int(rng.integers(1, 400))
                search = WindowSearch(planned, spec)
                for first in range(0, rows, size):
                    search.feed(t[first:first + size], values[first:first + size])
                assert search.finish() == find_window(t, planned, spec, values)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("n", [1, 2, 3])
def test_scalars_of_a_window_too_short_to_difference_are_finite(n: int) -> None:
    """A window of one or two samples (a session sampled slower than the window) gives
    finite features and no numpy warning: Hjorth parameters are 0 there."""
    x = np.arange(2.0 * n).reshape(n, 2)
    values, names = scalar_features(x, SCALARS, ["a", "b"])
    assert np.isfinite(values).all() and len(values) == len(names)


@pytest.mark.filterwarnings("error")
def test_online_row_holds_at_least_two_samples() -> None:
    """A hop whose window holds one sample (2 Hz data, 0.5 s window) uses the last two."""
    features = SessionFeatures()
    t = np.arange(10) * 0.5
    values = np.random.default_rng(0).normal(size=(10, len(features.channels())))
    row = features.online_rows(t, values, [5])[0]
    widened = scalar_features(values[4:6], list(features.scalars), features.channels(),
                              features.fft_k)[0]
    np.testing.assert_array_equal(row, widened)


@pytest.mark.parametrize("scalars", [SCALARS, ("range", "hjorth_mob", "hjorth_comp"),
                                     ("mean", "variance", "delta", "energy")])
def test_online_rows_equal_each_window_on_its_own(monkeypatch: pytest.MonkeyPatch,
                                                  scalars: tuple[str, ...]) -> None:
    """The hops of a replay, computed together (windows of unequal length on jittered
    times, widened windows of 2 samples, more than one block of values at a time; from
    shared segments where every scalar allows it) equal each window's features computed
    alone."""
    features = SessionFeatures(scalars=scalars, window_s=0.05)
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.0005, 0.0015, 3000))
    t[1000:] += 0.2  # a step longer than the window: its windows hold 2 samples
    values = 20.0 + rng.normal(size=(len(t), len(features.channels())))  # an offset, as tau
    ends = np.r_[0, 1, 2, np.arange(3, len(t), 7), 1000, 1001]
    monkeypatch.setattr(window_features, "ONLINE_BLOCK_VALUES", 5000)
    rows = features.online_rows(t, values, ends)
    for row, k in zip(rows, ends, strict=True):
        first = max(0, min(int(np.searchsorted(t, t[k] - 0.05, side="right")), k - 1))
        alone = scalar_features(values[first:k + 1], scalars, features.channels())[0]
        np.testing.assert_allclose(row, alone, rtol=1e-11, atol=1e-12)


def test_window_moments_equal_each_window_on_its_own() -> None:
    """Windows of 0 to some 60 elementary segments (every binary digit of the segment
    count taken from the doubled runs), overlapping at random on an offset series,
    have the moments of their samples alone: max and min exactly."""
    rng = np.random.default_rng(5)
    y = 20.0 + rng.normal(size=(700, 3))
    starts = rng.integers(0, 700, 80)
    stops = np.minimum(700, starts + rng.integers(0, 300, 80))
    stops[:3] = starts[:3]  # empty windows
    found = window_moments(y, starts, stops)
    for i, (a, b) in enumerate(zip(starts, stops, strict=True)):
        part = y[a:b] if b > a else np.zeros((1, 3))
        assert found.count[i, 0] == b - a
        np.testing.assert_allclose(found.mean[i], part.mean(axis=0), rtol=1e-13)
        np.testing.assert_allclose(found.var[i], part.var(axis=0) if b > a else 0.0,
                                   rtol=1e-11, atol=1e-15)
        np.testing.assert_array_equal(found.max[i], part.max(axis=0))
        np.testing.assert_array_equal(found.min[i], part.min(axis=0))
