"""scripts/contact_error.py: the contact share of a source."""

from __future__ import annotations

import numpy as np


def test_contact_counts_near_points_that_are_far_along_the_surface(contact_error) -> None:
    contact_shares = contact_error.contact_shares
    # A strip folded back on itself: points 0–4 on the lower sheet, 5–9 on the upper one,
    # 0.05 above; along the surface the sheets meet only at the fold (x = 1).
    x = np.linspace(0.0, 1.0, 5)
    vertices = np.concatenate(
        [np.stack([x, 0 * x, 0 * x], 1), np.stack([x, 0 * x + 0.05, 0 * x], 1)]
    )
    along = np.abs(x[:, None] - x[None, :])
    across = (1.0 - x[:, None]) + (1.0 - x[None, :]) + 0.05
    geodesic = np.block([[along, across], [across, along]])
    sources = np.array([0, 4])
    shares = contact_shares(vertices, sources, geodesic[sources], radius=0.08, stretch=3.0)
    # source 0 (far from the fold) sees point 5 just above it, 2.05 away along the surface;
    # source 4 sits at the fold: point 9 above it is 0.05 away along the surface too.
    np.testing.assert_allclose(shares, [1 / 10, 0.0])
    none = contact_shares(vertices, sources, geodesic[sources], radius=0.01, stretch=3.0)
    np.testing.assert_allclose(none, [0.0, 0.0])
