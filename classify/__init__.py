"""Classifiers and their honest evaluation."""
