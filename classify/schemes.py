"""Class schemes and contexts (thesis section 6.1.3).

=============  ==========================================  =========================
scheme         classes                                     mapping
=============  ==========================================  =========================
full           none, bump, adjust, shove                   as recorded
reaction       none, adjust, shove                         bump counts as none
contact        none, contact                               bump, adjust, shove merged
intentional    none, intentional                           bump counts as none;
                                                           adjust and shove merged
=============  ==========================================  =========================

The *limited* context (the thesis's Figure 6.9) removes the actions that were
hardest in each condition: shove from static sessions and adjust from dynamic
sessions. Those sessions are excluded, not relabelled.
"""

from __future__ import annotations

import numpy as np

from contactkit.errors import InputError, check_choice
from contactkit.schemas import ACTIONS

SCHEMES: dict[str, dict[str, str]] = {
    "full": {a: a for a in ACTIONS},
    "reaction": {"none": "none", "bump": "none", "adjust": "adjust", "shove": "shove"},
    "contact": {"none": "none", "bump": "contact", "adjust": "contact", "shove": "contact"},
    "intentional": {"none": "none", "bump": "none", "adjust": "intentional",
                    "shove": "intentional"},
}
LIMITED_DROP = {"static": "shove", "dynamic": "adjust"}


def check_scheme(scheme: str) -> str:
    """Return ``scheme`` if known, else raise InputError."""
    check_choice("class scheme", scheme, SCHEMES)
    return scheme


def scheme_classes(scheme: str) -> list[str]:
    """Return the class names of a scheme, in a fixed order (none first)."""
    mapping = SCHEMES[check_scheme(scheme)]
    return list(dict.fromkeys(mapping[a] for a in ACTIONS))


def relabel(actions: np.ndarray, scheme: str) -> np.ndarray:
    """Map recorded actions to the scheme's classes."""
    mapping = SCHEMES[check_scheme(scheme)]
    return np.array([mapping[a] for a in actions], dtype=object)


def limited_mask(actions: np.ndarray, conditions: np.ndarray) -> np.ndarray:
    """Return the sessions kept in the limited context."""
    return np.array([LIMITED_DROP.get(c) != a for a, c in zip(actions, conditions, strict=True)])


def check_two_classes(labels: np.ndarray, what: str) -> None:
    """Raise one :class:`InputError` line when ``labels`` hold fewer than two distinct
    classes, since no classifier can be fitted or evaluated on one class (``what`` names
    the job, e.g. "training")."""
    classes = sorted({str(c) for c in labels})
    if len(classes) < 2:
        found = f"only {classes[0]!r}" if classes else "no labelled rows"
        raise InputError(f"{what} needs at least two classes in the data; it has {found}")
