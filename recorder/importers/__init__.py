"""Reading other formats into sessions (joint arrays, CSV, ROS 1/2 bags, CAN logs), each
streamed through one writer, and writing sessions out as MCAP."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
# bag_salvage, can_codec, map_file and spill are the readers' parts.
__all__ = ["arrays", "bags", "can_map", "can_tools", "csv_import", "csv_map",
           "mcap_export", "writer"]
