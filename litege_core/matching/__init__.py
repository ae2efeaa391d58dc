"""Shape matching by coarse-to-fine argmin of a predicted distance (reference-spec §5).

* :class:`NNCache` — per-target multi-tier nearest-neighbour cache (farthest-point tiers by
  default, the reference's random tiers on request), pickle-free ``to_arrays``/``from_arrays``.
* :func:`coarse_to_fine_search` — batched beam search of all queries through the tiers with a
  caller-supplied ``score_fn``; :func:`exhaustive_search` is the slow all-points reference.
* :func:`coverage_radius`, :func:`max_evaluations` — diagnostics of a cache configuration.
"""

from litege_core.matching.cache import (
    DEFAULT_NEIGHBOURS,
    DEFAULT_TIER_SIZES,
    NNCache,
    TierStrategy,
    coverage_radius,
)
from litege_core.matching.search import (
    DEFAULT_BEAMS,
    ScoreFn,
    coarse_to_fine_search,
    exhaustive_search,
    max_evaluations,
    resolve_beams,
)

__all__ = [
    "DEFAULT_BEAMS",
    "DEFAULT_NEIGHBOURS",
    "DEFAULT_TIER_SIZES",
    "NNCache",
    "ScoreFn",
    "TierStrategy",
    "coarse_to_fine_search",
    "coverage_radius",
    "exhaustive_search",
    "max_evaluations",
    "resolve_beams",
]
