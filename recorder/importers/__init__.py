"""Reading other formats into sessions (joint arrays, CSV, ROS 1/2 bags, CAN logs), one
registered reader per format (:mod:`.base`, :mod:`.registry`; plugins through the
``contactkit.importers`` entry-point group), each streamed through one writer
(:mod:`.writer`, run by :mod:`.jobs`), and writing sessions out as MCAP."""
