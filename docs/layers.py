"""Draw the layers of contactkit (docs/explanation/layers.png) from the one table that
states them, ``LAYERS`` in tests/test_layering.py. Arrows point from a layer to the
layers it may import; arrows implied by others (a -> b -> c makes a -> c) are left out.

Run from the repository root: ``.venv/bin/python docs/layers.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.test_layering import LAYERS  # noqa: E402

OUT = ROOT / "docs" / "explanation" / "layers.png"
# Where each layer sits (x, y) and what it holds.
PLACES = {
    "contactkit.cli": (2.0, 5.0, "the commands: recorder, replay, classify\n(composition roots)"),
    "contactkit.recorder": (1.3, 4.0, "sim · sources · capture\nimporters · stats"),
    "contactkit.replay": (3.6, 4.0, "replay engine, Rerun recording"),
    "contactkit.viewer": (0.1, 2.9, "Rerun layout, palette,\nweb viewer"),
    "contactkit.classify": (3.7, 2.9, "kinds · modelfile · events\nexperiments · training,\n"
                                      "evaluation, prediction"),
    "contactkit.features": (2.4, 1.9, "observer, chain, detector,\nisolation, windows"),
    "contactkit.schemas": (2.0, 0.9, "columns · metadata · session\ndataset · feature tables"),
    "base": (2.0, -0.1, "contactkit.errors · contactkit.util · contactkit.robots\n"
                       "(everything may use these)"),
}


def reduced_edges() -> list[tuple[str, str]]:
    """Return the layer dependencies (from, to) without those implied by others."""
    deps = {layer: set(allowed) for layer, allowed in LAYERS.items()}

    def reachable(start: str, skip: str) -> set[str]:
        seen: set[str] = set()
        todo = [d for d in deps[start] if d != skip]
        while todo:
            node = todo.pop()
            if node not in seen:
                seen.add(node)
                todo += deps[node]
        return seen

    return [(a, b) for a in deps for b in sorted(deps[a]) if b not in reachable(a, b)]


def draw(out: Path = OUT) -> Path:
    """Draw the layer figure; return the path of the PNG written."""
    fig, ax = plt.subplots(figsize=(8, 6.2))
    for a, b in reduced_edges():
        (xa, ya, _), (xb, yb, _) = PLACES[a], PLACES[b]
        ax.annotate("", xy=(xb, yb + 0.28), xytext=(xa, ya - 0.28),
                    arrowprops={"arrowstyle": "->", "color": "0.45", "lw": 1.2})
    for layer, (x, y, text) in PLACES.items():
        name = "base" if layer == "base" else layer.removeprefix("contactkit.")
        ax.text(x, y, f"{name}\n{text}", ha="center", va="center", fontsize=8.5,
                bbox={"boxstyle": "round,pad=0.45", "fc": "#eef3fb" if layer != "base"
                      else "#f4f4f4", "ec": "#4a6fa5"})
    ax.set_xlim(-0.9, 4.7)
    ax.set_ylim(-0.7, 5.6)
    ax.axis("off")
    ax.set_title("contactkit's layers: an arrow means 'may import' (tests/test_layering.py)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(draw())
