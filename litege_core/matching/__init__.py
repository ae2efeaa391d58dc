"""Shape matching by coarse-to-fine argmin of a predicted distance (reference-spec §5).

* :class:`NNCache` — per-target multi-tier nearest-neighbour cache (farthest-point tiers by
  default, the reference's random tiers on request), pickle-free ``to_arrays``/``from_arrays``.
* :func:`coarse_to_fine_search` — batched beam search of all queries through the tiers with a
  caller-supplied ``score_fn``; :func:`exhaustive_search` is the slow all-points reference.
* :func:`coverage_radius`, :func:`max_evaluations` — diagnostics of a cache configuration.
* :class:`MatchingModel` — a matching bundle (T-Net, basis, network(s)): ``prepare`` shapes
  into :class:`MatchingShape` objects, then ``match`` queries of X on Y (:class:`MatchResult`).
"""

from litege_core.matching.bundle import (
    MatchingBundle,
    SearchSettings,
    load_matching_bundle,
    save_matching_bundle,
    shipped_matching_bundles,
)
from litege_core.matching.cache import (
    DEFAULT_NEIGHBOURS,
    DEFAULT_TIER_SIZES,
    NNCache,
    TierStrategy,
    coverage_radius,
)
from litege_core.matching.frame import MatchingPipeline
from litege_core.matching.model import MatchingModel, MatchingShape, MatchResult
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
    "MatchResult",
    "MatchingBundle",
    "MatchingModel",
    "MatchingPipeline",
    "MatchingShape",
    "NNCache",
    "ScoreFn",
    "SearchSettings",
    "TierStrategy",
    "coarse_to_fine_search",
    "coverage_radius",
    "exhaustive_search",
    "load_matching_bundle",
    "max_evaluations",
    "resolve_beams",
    "save_matching_bundle",
    "shipped_matching_bundles",
]
