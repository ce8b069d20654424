"""The order in which the safety filter prefers actions: the badness of an action that does not pass the
one-period test (:mod:`softreach.filters.judge`), and the scores by which the filter's rules
choose among candidates (:class:`~softreach.filters.ValueFilter`, :mod:`softreach.filters.compiled`,
:mod:`softreach.filters.judge`). Lower is better everywhere.

An action that passes scores its worst next certificate, a number of the table's scale, far below
:data:`NEXT_CAP`. A failing action's badness is its rank plus its tie (``atan`` of its next certificate over
``pi``, within ``(-0.5, 0.5)``, plus the overspend times :data:`TIE_OVERSPEND`): the ranks lie at least
:data:`NEXT_CAP` apart, more than any tie, so the rank decides first.

numba reads these module globals as compile-time constants: the compiled code is that of the literals.
"""

from __future__ import annotations

#: a next value enters a score capped here; ranks lie at least this far apart, more than any tie
NEXT_CAP = 1e5
#: switch rule: the score of a candidate that passes but after which no action is known to pass again is this
#: plus its next value (capped at ``NEXT_CAP``): after every candidate that keeps, before every one that fails
PASSES_ONLY = 5e5
#: smooth rule: the score of a candidate that passes but does not keep is this plus its normalised distance to the
#: policy's action (at most ``2 sqrt(m)``, below 10 for fewer than 25 controls): after every one that keeps
SMOOTH_PASSES_ONLY = 10.0
#: badness rank of an action whose end box lies in the safe cells (they prove ``C1`` and the budget for good)
RANK_PROVEN = 0.9e6
#: badness rank of an action whose motion keeps ``C1`` and whose end box the safe value keeps (``V_safe <= 0``)
RANK_SAFE = 1e6
#: badness rank of an action whose motion keeps ``C1`` but whose end box the safe value does not keep
RANK_UNSAFE = 3e6
#: added to the rank of an action whose period may overspend the budget (``z_end < 0``)
RANK_OVERSPENT = 1e6
#: badness of an action whose motion may leave ``C1``: this plus how far (the largest ``c1`` over its box)
RANK_LEAVES_C1 = 5e6
#: below this score no failing candidate can be chosen: its badness is at least ``RANK_PROVEN`` less half a tie
LOWEST_BAD = RANK_PROVEN - 1.0
#: a tie's next certificate of ``+inf`` is read as this (mapped by ``atan`` just below ``0.5``)
TIE_INF = 1e12
#: a tie's weight of the overspend ``max(-z_end, 0)`` [value units per second of budget]
TIE_OVERSPEND = 1e3
