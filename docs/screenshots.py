"""The site's screenshots of the Rerun view, made from the demo replay.

`make docs` runs the browser check on `demo.rrd` with the time cursor inside the demo's
contact (`tools/viewer_check.py demo.rrd --cursor 0.5 --out build/screenshots`), so the
pictures show the view as the code draws it today. ``docs/hooks.py`` then puts that
screenshot on the site as ``viewer.png``, and :func:`annotate` numbers its panels into
``viewer-annotated.png`` for the "Read the Rerun view" tutorial. Where no browser
could run, the site keeps the committed copies in ``docs/`` and the build says so.

    python docs/screenshots.py build/screenshots/demo.png docs/   # refresh the copies
"""

from __future__ import annotations

import sys
from pathlib import Path

SHOT = Path(__file__).resolve().parents[1] / "build" / "screenshots" / "demo.png"
"""Where `make docs` leaves the browser check's screenshot of the demo replay."""

MARKERS = (
    (1, (30, 95), "3-D view"),
    (2, (690, 95), "joint torque"),
    (3, (690, 335), "observer residual"),
    (4, (690, 485), "estimated and applied force"),
    (5, (690, 655), "class probability"),
    (6, (1500, 850), "state lanes"),
    (7, (45, 955), "events log"),
)
"""The numbered badges: number, centre (x, y) [px] in the 1600x1000 screenshot, panel.
The positions follow the panels of ``replay_blueprint()`` (contactkit/viewer/layout.py)
at the browser check's viewport; the tutorial's key uses the same numbers."""

BADGE_RADIUS_PX = 17
BADGE_COLOUR = (220, 30, 90)


def annotate(src: Path, dst: Path) -> Path:
    """Draw the numbered badges of :data:`MARKERS` on the screenshot ``src`` and write
    the result to ``dst`` (PNG); return ``dst``."""
    from PIL import Image, ImageDraw, ImageFont

    image = Image.open(src).convert("RGB")
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=22)
    r = BADGE_RADIUS_PX
    for number, (x, y), _ in MARKERS:
        draw.ellipse((x - r, y - r, x + r, y + r), fill=BADGE_COLOUR, outline="white",
                     width=3)
        draw.text((x, y), str(number), fill="white", font=font, anchor="mm")
    dst.parent.mkdir(parents=True, exist_ok=True)
    image.save(dst, format="PNG", optimize=True)
    return dst


if __name__ == "__main__":
    shot, docs = Path(sys.argv[1]), Path(sys.argv[2])
    (docs / "viewer.png").write_bytes(shot.read_bytes())
    annotate(shot, docs / "viewer-annotated.png")
