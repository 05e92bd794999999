"""The one registry class behind sources, importers, model kinds and robots."""

from __future__ import annotations

import importlib.metadata

import pytest

from contactkit.errors import InputError
from contactkit.util.plugins import Registry, subclass_check


class Base:
    """What the test registry holds."""


class Child(Base):
    """A complete subclass."""


GROUP = "contactkit.test-plugins"


def _registry(monkeypatch: pytest.MonkeyPatch, *points: tuple[str, str]) -> Registry[type]:
    entries = [importlib.metadata.EntryPoint(name, value, GROUP) for name, value in points]
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: entries if group == GROUP else [])
    return Registry("widget", GROUP, {"builtin": f"{__name__}:Child"},
                    subclass_check("widget", Base), reserved=("alias",))


def test_names_come_without_importing_and_builtins_cannot_be_taken_over(monkeypatch) -> None:
    registry = _registry(monkeypatch, ("zeta", "contactkit_absent_widget:W"),
                         ("builtin", "contactkit_absent_widget:X"),
                         ("alias", "contactkit_absent_widget:Y"),
                         ("alpha", f"{__name__}:Child"))
    assert registry.names() == ["builtin", "alpha", "zeta"]
    assert registry.get("builtin") is Child and registry.get("alpha") is Child
    with pytest.raises(InputError, match=r"widget 'zeta' \(contactkit_absent_widget:W\) "
                                         "cannot be loaded"):
        registry.get("zeta")
    with pytest.raises(InputError, match=r"unknown widget 'nope' \(expected one of "
                                         "builtin, alpha, zeta\\)"):
        registry.get("nope")
    loaded, problems = registry.load_all()
    assert set(loaded) == {"builtin", "alpha"} and list(problems) == ["zeta"]


def test_a_target_that_fails_its_check_is_refused_in_one_line(monkeypatch) -> None:
    registry = _registry(monkeypatch, ("base", f"{__name__}:GROUP"))
    with pytest.raises(InputError, match="is not a complete Base subclass"):
        registry.get("base")


def test_register_replace_unregister_and_refresh(monkeypatch) -> None:
    registry = _registry(monkeypatch)

    class Other(Base):
        pass

    assert registry.register("builtin", Child) is Child  # the same thing again: fine
    with pytest.raises(InputError, match="widget 'builtin' is already registered"):
        registry.register("builtin", Other)
    registry.register("builtin", Other, replace=True)
    assert registry.get("builtin") is Other
    registry.register("mine", Other)
    assert "mine" in registry and registry.names()[-1] == "mine"
    registry.unregister("mine")
    assert "mine" not in registry
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [importlib.metadata.EntryPoint(
                            "late", f"{__name__}:Child", GROUP)])
    assert "late" not in registry  # the entry points were read once
    registry.refresh()
    assert registry.get("late") is Child
