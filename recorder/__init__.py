"""Recording: sources (simulated Panda, CAN), capture protocol, crash-safe writer, datasets."""
