"""The simulated arm: rigid-body dynamics with friction and noise, a person's touches, free
motion, and simulated datasets built from presets."""

# The public modules, for the API reference (submodule names: importing the package
# stays light).
__all__ = ["dataset", "forces", "motion", "noise", "simulator"]
