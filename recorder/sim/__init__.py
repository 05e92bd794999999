"""The simulated arm: rigid-body dynamics with friction and noise, a person's touches, free
motion, and simulated datasets built from presets."""
