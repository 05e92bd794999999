"""Reading other formats into sessions (joint arrays, CSV, ROS 1/2 bags, CAN logs), one
registered reader per format (:mod:`.base`, :mod:`.registry`; plugins through the
``contactkit.importers`` entry-point group), each streamed through one writer
(:mod:`.writer`, run by :mod:`.jobs`), and writing sessions out as MCAP."""

# The public modules, for the API reference (submodule names: importing the package
# stays light). bag_salvage, can_codec, map_file and spill are the readers' parts.
__all__ = ["arrays", "bags", "base", "can_map", "can_tools", "csv_import", "csv_map",
           "jobs", "mcap_export", "registry", "writer"]
