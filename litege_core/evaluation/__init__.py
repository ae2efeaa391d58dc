"""Evaluation protocols: geodesic regression (and, later, matching) against baselines."""

__all__: list[str] = []
