"""The decision's numbers, in one home: the reason codes of :meth:`~softreach.filters.ValueFilter.filter`'s decisions
(``info["reason"]``; the wrapper's ``info["filter_reason"]`` is their name in :data:`REASONS`), and the order in which
it ranks actions that do not pass (:func:`softreach.filters.judge.badness`), lower first: a failing action's badness
is its rank plus its tie (``atan`` of its next table value over ``pi``, plus the overspend times
:data:`TIE_OVERSPEND`); ranks lie at least ``1e6`` apart, so the rank decides first. numba compiles these globals as
constants."""

from __future__ import annotations

#: the policy's action passed the one-period test and was applied unchanged
PASS = 0
#: smooth rule: a point between the policy's action and a certified candidate was applied
BLEND = 1
#: the certified candidate with the lowest next table value (at its end box's centre) was applied
OPTIMAL = 2
#: the state lies outside the table's grid: the least-bad candidate was applied, nothing is guaranteed
OUTSIDE = 3
#: the time is at or after the table's horizon
AFTER_HORIZON = 4
# (5 is not used: a non-finite table value reads as unsafe, ``+inf``, and the state is ``UNCERTIFIED`` or ``OUTSIDE``)
#: no candidate could even be bounded (the model's enclosure failed): the fallback action was applied
FALLBACK = 6
#: inside the table, but no held action passes the test: the least-bad candidate was applied
UNCERTIFIED = 7
#: reason code -> name (the wrapper's ``info["filter_reason"]``)
REASONS = {PASS: "pass", BLEND: "blend", OPTIMAL: "optimal", OUTSIDE: "outside_domain",
           AFTER_HORIZON: "after_horizon", FALLBACK: "fallback", UNCERTIFIED: "uncertified"}

#: badness rank of an action whose period keeps ``C1`` and the budget
RANK_KEPT = 1e6
#: badness rank of an action whose period keeps ``C1`` but may overspend the budget (``z_end < 0``)
RANK_OVERSPENT = 3e6
#: badness of an action whose motion may leave ``C1``: this plus the largest ``c1``
RANK_LEAVES_C1 = 5e6
#: a tie's next value of ``+inf`` is read as this
TIE_INF = 1e12
#: a tie's weight of the overspend ``max(-z_end, 0)`` [value units per second of budget]
TIE_OVERSPEND = 1e3
