"""Shared helpers below every subpackage: progress bars, pacing, parallel work, CLI runner."""
