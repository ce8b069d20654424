"""softreach.filters: a least-restrictive safety filter built on a ``W_eps`` table (paper §V).

* :class:`ValueFilter` — the pure, batched core (numpy in/out, torch in/out): the one-period look-ahead of
  held actions (:class:`Lookahead`), certification, the ``"switch"`` and ``"smooth"`` rules;
* :class:`SafetyFilter` — a ``gymnasium.Wrapper`` that filters any policy's actions in the landing
  environments;
* :class:`VecSafetyFilter` — one batched decision per step for SB3's ``DummyVecEnv`` of filtered environments.
"""

from .core import (AFTER_HORIZON, BLEND, CERTIFY_REASONS, FALLBACK, NO_PLAN, OPTIMAL, OUTSIDE, PASS,
                   PLAN_LAND, PLAN_SAFE, REASONS, RULES, UNCERTIFIED, ValueFilter)
from softreach.reach.proof.lookahead import Lookahead
from softreach.reach.tables.field import TableField
from .wrapper import SafetyFilter
from .vector import VecSafetyFilter

__all__ = ["AFTER_HORIZON", "BLEND", "CERTIFY_REASONS", "FALLBACK", "Lookahead", "NO_PLAN", "OPTIMAL",
           "OUTSIDE", "PASS", "PLAN_LAND", "PLAN_SAFE", "REASONS", "RULES", "SafetyFilter", "TableField", "UNCERTIFIED", "ValueFilter",
           "VecSafetyFilter"]
