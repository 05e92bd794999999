"""Fuzzing the inputs issue 25 made strict: ``--meta`` pairs, the time rule, text shown
on the terminal and the overwrite policy of the one writer. Hypothesis profile as in
tests/test_fuzz.py (``ci`` in ``make test``, ``long`` in benchmarks/bench_fuzz.py)."""

from __future__ import annotations

import math
import unicodedata
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from contactkit.errors import InputError
from contactkit.recorder.importers.writer import parse_meta
from contactkit.schemas.columns import MAX_ABS_T_S, MAX_STEP_S, MIN_STEP_S, check_times
from contactkit.util import atomic
from contactkit.util.owned import owned_by_marker
from contactkit.util.safe_open import parse_json
from contactkit.util.text import printable
from tests.fuzz_support import FLOATS, refused_or

KEYS = st.sampled_from(["with_hand", "planned_at_s", "pose", "notes", "operator", "link",
                        "events", "source_info", "no_such_key", ""])


@given(pairs=st.lists(st.tuples(KEYS, st.text(max_size=300)), max_size=4))
def test_fuzz_meta_pairs(pairs) -> None:
    doc = refused_or(parse_meta, [f"{k}={v}" for k, v in pairs])
    if doc is not None and "with_hand" in doc:
        assert isinstance(doc["with_hand"], bool)


@given(t=st.lists(FLOATS, max_size=50) | st.lists(
    st.floats(min_value=-1e12, max_value=1e12), min_size=2, max_size=50).map(sorted))
def test_fuzz_time_rule(t) -> None:
    try:
        check_times(np.array(t, dtype=float))
    except InputError as err:
        assert "\n" not in str(err) and len(str(err)) < 400
        return
    steps = np.diff(t)
    assert all(math.isfinite(v) and abs(v) <= MAX_ABS_T_S for v in t)
    assert (steps >= MIN_STEP_S).all() and (steps <= MAX_STEP_S).all()


@given(text=st.text(alphabet="[]{}\",:0123456789.eE-+ abtrunlfsNIa\\", max_size=300)
       | st.builds(lambda n, inner: "[" * n + inner + "]" * n, st.integers(0, 3000),
                   st.sampled_from(["", "1", "{}", "1" * 400])))
def test_fuzz_bounded_json(text) -> None:
    """Any text is a JSON value within the bounds or one short InputError line (never a
    RecursionError or the int parser's ValueError)."""
    value = refused_or(parse_json, text, "fuzzed JSON")
    del value


@given(name=st.text(min_size=1, max_size=300).filter(lambda n: "/" not in n and "\0" not in n))
def test_fuzz_temporary_names_fit(name) -> None:
    stem = atomic.temporary_stem(name)
    assert len(stem.encode(errors="surrogateescape")) <= atomic.MAX_TEMPORARY_STEM_BYTES
    assert stem == name or len(name.encode(errors="surrogateescape")) > 200


@given(text=st.text(max_size=200))
def test_fuzz_printable_text(text) -> None:
    shown = printable(text)
    assert not any(unicodedata.category(c) in ("Cc", "Cf") for c in shown)


@pytest.fixture(scope="module")
def writer_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("writer")


@given(existing=st.sampled_from(["none", "file", "link", "dir", "owned"]),
       overwrite=st.booleans(), owned=st.booleans(), data=st.binary(max_size=100))
def test_fuzz_overwrite_policy(writer_dir, existing, overwrite, owned, data) -> None:
    victim = writer_dir / "victim"
    victim.write_bytes(b"victim")
    target = writer_dir / "target"
    for path in (target,):
        if path.is_symlink() or path.is_file():
            path.unlink()
        elif path.is_dir():
            path.rmdir()
    if existing == "file":
        target.write_bytes(b"foreign")
    elif existing == "owned":
        target.write_bytes(b"MINE old")
    elif existing == "link":
        target.symlink_to(victim)
    elif existing == "dir":
        target.mkdir()
    policy = owned_by_marker(b"MINE") if owned else None
    written = refused_or(atomic.write_bytes, target, b"MINE" + data, overwrite=overwrite,
                         owned=policy)
    assert victim.read_bytes() == b"victim"
    if written is not None:
        assert target.read_bytes() == b"MINE" + data and not target.is_symlink()
        assert existing in ("none", "owned") or overwrite
    assert not [p for p in writer_dir.iterdir() if ".contactkit-" in p.name]
