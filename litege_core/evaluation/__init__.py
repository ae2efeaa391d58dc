"""Evaluation protocols: geodesic regression (and, later, matching) against baselines."""
