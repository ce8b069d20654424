"""The order in which the safety filter prefers actions (:mod:`softreach.filters.judge`,
:mod:`softreach.filters.compiled`); lower is better. A passing action scores its worst next certificate, far below
:data:`NEXT_CAP`. A failing one's badness is its rank plus its tie (``atan`` of its next certificate over ``pi``,
plus the overspend times :data:`TIE_OVERSPEND`): ranks lie at least :data:`NEXT_CAP` apart, so the rank decides
first. numba compiles these globals as constants.
"""

from __future__ import annotations

#: a next value enters a score capped here; ranks lie at least this far apart, more than any tie
NEXT_CAP = 1e5
#: switch rule: score of a passing candidate after which no action is known to pass, plus its capped next value
PASSES_ONLY = 5e5
#: smooth rule: such a candidate's score, plus its distance to the policy's action (``2 sqrt(m) < 10``, ``m < 25``)
SMOOTH_PASSES_ONLY = 10.0
#: badness rank of an action whose end box lies in the safe cells
RANK_PROVEN = 0.9e6
#: badness rank of an action that keeps ``C1`` and ends where ``V_safe <= 0``
RANK_SAFE = 1e6
#: badness rank of an action that keeps ``C1`` only
RANK_UNSAFE = 3e6
#: added to the rank of an action whose period may overspend the budget (``z_end < 0``)
RANK_OVERSPENT = 1e6
#: badness of an action whose motion may leave ``C1``: this plus the largest ``c1``
RANK_LEAVES_C1 = 5e6
#: every failing candidate's badness lies above this
LOWEST_BAD = RANK_PROVEN - 1.0
#: a tie's next certificate of ``+inf`` is read as this
TIE_INF = 1e12
#: a tie's weight of the overspend ``max(-z_end, 0)`` [value units per second of budget]
TIE_OVERSPEND = 1e3
