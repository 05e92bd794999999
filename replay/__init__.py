"""Replay of sessions through the feature chain and classifier, logged to Rerun."""
