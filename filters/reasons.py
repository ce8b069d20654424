"""The reason codes of :meth:`~softreach.filters.ValueFilter.filter`'s decisions (``info["reason"]``; the wrapper's
``info["filter_reason"]`` is their name in :data:`REASONS`), written alike by :mod:`softreach.filters.compiled`."""

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
