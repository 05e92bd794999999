"""The contact isolator of the simulated and real Panda: its model and the collision
meshes the simulator applies contacts on (the one place that names both for
:mod:`contactkit.features.isolation`)."""

from __future__ import annotations

from contactkit.features.dynamics import PandaModel
from contactkit.features.isolation import ContactIsolator, IsolatorConfig
from contactkit.recorder.forces import link_surface


def panda_isolator(with_hand: bool, config: IsolatorConfig | None = None) -> ContactIsolator:
    """Return the isolator of the Panda with or without its hand (link 7's surface
    then includes the hand)."""
    return ContactIsolator(PandaModel(with_hand), lambda k: link_surface(k, with_hand), config)
