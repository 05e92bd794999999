"""Reading other formats into sessions (joint arrays, CSV, ROS 1/2 bags, CAN logs), each
streamed through one writer, and writing sessions out as MCAP."""
