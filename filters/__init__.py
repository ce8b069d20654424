"""softreach.filters: a least-restrictive safety filter on a ``W_eps`` table (paper §V; docs/filters.md): the batched
core :class:`ValueFilter`, the ``gymnasium.Wrapper`` :class:`SafetyFilter`, and :class:`VecSafetyFilter` for SB3."""

from .core import (AFTER_HORIZON, BLEND, CERTIFY_REASONS, FALLBACK, NO_PLAN, OPTIMAL, OUTSIDE, PASS,
                   PLAN_LAND, PLAN_SAFE, REASONS, RULES, UNCERTIFIED, ValueFilter)
from softreach.reach.proof.lookahead import Lookahead
from softreach.reach.tables.field import TableField
from .wrapper import SafetyFilter
from .vector import VecSafetyFilter

__all__ = ["AFTER_HORIZON", "BLEND", "CERTIFY_REASONS", "FALLBACK", "Lookahead", "NO_PLAN", "OPTIMAL",
           "OUTSIDE", "PASS", "PLAN_LAND", "PLAN_SAFE", "REASONS", "RULES", "SafetyFilter", "TableField",
           "UNCERTIFIED", "ValueFilter", "VecSafetyFilter"]
