"""Recognition by fit where the classifier is unsure (issue 40, item 3).

On a cell every part has depth. Where the classifier's margin (best minus second-best score,
summed over the views) is low, its first choice is little better than its next ones, and the
templates' fit to the depth tells parts apart that a 60 px crop does not. Such a part's class
candidates are then the classifier's ranking down to ``ClassifyParams.fit_rank_max_candidates``
parts (up to all of them), instead of its best ``class_candidates``; the pose stage fits each
(``PerceptionPipeline.fit_part``, the table path, unpolished) and the best fit names the part.
With ``FitParams.fit_rank_min_fitness`` a part that no candidate fits that well is reported
unknown rather than as the least bad fit.

The budget is a count of candidates, not wall time, so the result does not depend on the host's
speed; each candidate costs one table-path fit (``tlessbot bench fit-ranking`` measures it).

Between the classifier and pose nodes the candidates travel in a 16UC<k> image, at most
:data:`MAX_CHANNELS`: there the ranking is cut to that many (:func:`candidate_channels`).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

MAX_CHANNELS = 4   # a 16UC4 image: the most candidates the classifier node can send


def candidate_channels(class_candidates: int, below_margin: float, max_candidates: int) -> int:
    """Channels of the classifier node's candidate image: ``class_candidates``, or with fit
    ranking on (``below_margin > 0``) as many as its budget asks, up to :data:`MAX_CHANNELS`."""
    if below_margin <= 0:
        return class_candidates
    budget = MAX_CHANNELS if max_candidates <= 0 else max_candidates
    return max(class_candidates, min(budget, MAX_CHANNELS))


def ranking_depth(class_candidates: int, below_margin: float, max_candidates: int,
                  n_classes: int) -> int:
    """How many of the classifier's ranked classes a frame needs: ``class_candidates``, or the
    fit-ranking budget (0 = every class) when fit ranking is on (``below_margin > 0``)."""
    if below_margin <= 0:
        return class_candidates
    budget = n_classes if max_candidates <= 0 else min(max_candidates, n_classes)
    return max(class_candidates, budget)


def fit_ranked(margin: float, ranked: Sequence[int], margin_scale: float, *,
               below_margin: float, max_candidates: int) -> tuple[int, ...] | None:
    """The candidates to rank by fit for a part the classifier names with ``margin``, or None
    when it is sure enough (or fit ranking is off, ``below_margin`` 0).

    Args:
        margin: the part's classifier margin (summed over the views).
        ranked: its classes, best first (at least ``max_candidates`` when there are as many).
        margin_scale: the model's median margin on its training crops; without one (0) the
            threshold is ``below_margin`` itself, in score units.
        below_margin: fit ranking below ``below_margin * margin_scale``.
        max_candidates: at most this many candidates (0 = all of ``ranked``).
    """
    if below_margin <= 0:
        return None
    limit = below_margin * margin_scale if margin_scale > 0 else below_margin
    if not np.isfinite(margin) or margin >= limit:
        return None
    count = len(ranked) if max_candidates <= 0 else max_candidates
    return tuple(int(c) for c in ranked[:count])
