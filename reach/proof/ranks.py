"""The order in which the safety filter ranks actions that do not pass (:func:`softreach.filters.judge.badness`),
lower first: a failing action's badness is its rank plus its tie (``atan`` of its next table value over ``pi``, plus
the overspend times :data:`TIE_OVERSPEND`); ranks lie at least ``1e6`` apart, so the rank decides first. numba
compiles these globals as constants."""

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
