"""The colours every picture of contactkit shares (RGB, 0-255): one per class and one per
joint, so the Rerun view and the stats report's figures read alike. Plain tuples: no
Rerun or Matplotlib import."""

from __future__ import annotations

CLASS_COLORS = {"none": (160, 160, 160), "bump": (66, 135, 245), "adjust": (60, 180, 75),
                "shove": (230, 60, 60), "contact": (230, 140, 40),
                "intentional": (150, 80, 200)}
JOINT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
                (148, 103, 189), (140, 86, 75), (227, 119, 194)]
