"""The replay's default hop, apart from the engine (the chain and the classifier) so that
``replay --help`` shows it without importing them."""

DEFAULT_HOP_S = 0.02
"""Time between classifier runs on the sliding window [s]."""
