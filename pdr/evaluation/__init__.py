"""Scoring of firetrack's algorithms against ground truth (pure functions)."""
