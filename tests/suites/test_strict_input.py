"""Strict input parsing (issue 25): unknown map keys with a did-you-mean, strict
booleans, bounded values and messages, escaped terminal output."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from contactkit.cli.common import run_app
from contactkit.cli.recorder import app
from contactkit.errors import InputError
from contactkit.recorder.importers.can_map import load_map
from contactkit.recorder.importers.csv_map import load_csv_map, mindlab_map_path
from contactkit.recorder.importers.writer import parse_meta
from contactkit.schemas import read_session, write_session
from contactkit.util.text import printable
from tests.conftest import make_session

CAN_MAP = Path(load_map().source)


@pytest.mark.parametrize(("text", "old", "new", "hint"), [
    ("csv", '[q]\ncolumns = "q{j}"\nunit', '[q]\ncolumns = "q{j}"\nunits', "did you mean 'unit'"),
    ("csv", '[time]\ncolumn', '[time]\ncolum',
     r"missing key 'column' in \[time\] \(found 'colum'"),
    ("csv", '\nindex_base', '\nindex_bse', "did you mean 'index_base'"),
    ("can", 'start = 0, type = "int32"', 'start = 0, byte_oder = "big", type = "int32"',
     "did you mean 'byte_order'"),
    ("can", "sync_id", "sync_di", "did you mean 'sync_id'"),
    ("can", "counts_per_rad_s = 166886.0", "counts_per_rad_s = 166886.0\ncount_per_rad = 1.0",
     "no signal uses"),
])
def test_unknown_map_keys_are_errors_with_a_hint(text, old, new, hint, tmp_path) -> None:
    source = mindlab_map_path() if text == "csv" else CAN_MAP
    changed = source.read_text().replace(old, new, 1)
    assert changed != source.read_text()
    path = tmp_path / "map.toml"
    path.write_text(changed)
    with pytest.raises(InputError, match=hint):
        (load_csv_map if text == "csv" else load_map)(path)


def test_deeply_nested_maps_are_one_line(tmp_path) -> None:
    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    for load in (load_csv_map, load_map):
        with pytest.raises(InputError) as err:
            load(path)
        assert "\n" not in str(err.value) and len(str(err.value)) < 600


@pytest.mark.parametrize(("raw", "value"), [("true", True), ("False", False), ("0", False),
                                            ("1", True), ("FALSE", False)])
def test_booleans_parse_strictly(raw, value) -> None:
    assert parse_meta([f"with_hand={raw}"])["with_hand"] is value


@pytest.mark.parametrize("raw", ["no", "maybe", "yes", "", "2", "nein"])
def test_booleans_that_are_not_refuse(raw) -> None:
    with pytest.raises(InputError, match="with_hand must be true or false"):
        parse_meta([f"with_hand={raw}"])


def test_messages_quote_at_most_about_200_characters() -> None:
    with pytest.raises(InputError) as err:
        parse_meta(["no_such_key=" + "x" * 50_000])
    assert len(str(err.value)) < 600
    with pytest.raises(InputError, match="at most"):
        parse_meta(["notes=" + "x" * 50_000])
    parse_meta(["planned_at_s=" + "9" * 5000])  # a 5000-digit number is no traceback
    parse_meta(["notes=" + "[" * 5000])


def test_info_escapes_control_characters(tmp_path, capsys) -> None:
    path = make_session(tmp_path)
    session = read_session(path)
    evil = replace(session.meta, operator="\x1b[2J\x1b]0;owned\x07lab", notes="[red]x[/]\r")
    out = tmp_path / "evil.parquet"
    write_session(out, {n: session.column(n) for n in session.table.column_names}, evil)
    assert run_app(app, "recorder", ["info", str(out)]) == 0
    shown = capsys.readouterr().out
    assert "\x1b" not in shown and "\x07" not in shown and "\r" not in shown
    assert "\\x1b[2J" in shown and "[red]x[/]" in shown
    assert printable("a\u202eb") == "a\\u202eb"


def test_file_names_cannot_drive_the_terminal(tmp_path, capsys) -> None:
    """A file named with escape sequences or console markup is printed as named, escaped,
    in error lines and in the problem lists of directory commands."""
    from contactkit.cli.classify import app as classify_app
    from contactkit.cli.replay import app as replay_app

    make_session(tmp_path, duration_s=2.0, planned_at_s=1.0)
    hostile = ["bad\x1b]0;title\x07\x1b[2J.parquet", "[bold red]styled.parquet"]
    for name in hostile:
        (tmp_path / name).write_bytes(b"garbage")
    runs = [(replay_app, "replay", [str(tmp_path / hostile[0]), "--viewer", "none"]),
            (classify_app, "classify", ["features", str(tmp_path), "--out",
                                        str(tmp_path / "f.parquet")]),
            (app, "recorder", ["stats", str(tmp_path), "--out", str(tmp_path / "r")])]
    for tool, prog, argv in runs:
        code = run_app(tool, prog, argv)
        out, err = capsys.readouterr()
        assert code == 2 or prog == "recorder", (prog, err)
        assert "\x1b" not in out + err and "\x07" not in out + err, (prog, err)
        assert "bad\\x1b]0;title\\x07\\x1b[2J.parquet" in " ".join((out + err).split()), err
        if prog != "replay":
            assert "[bold red]styled.parquet" in err + out, (prog, err)
