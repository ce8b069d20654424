"""softreach.filters: a least-restrictive safety filter built on a ``W_eps`` table (paper §V).

* :class:`ValueFilter` — the pure, batched core (numpy in/out, torch in/out): value, computed margin, the
  ``"switch"`` and ``"smooth"`` rules;
* :class:`SafetyFilter` — a ``gymnasium.Wrapper`` that filters any policy's actions in the landing
  environments.
"""

from .core import (AFTER_HORIZON, BLEND, FALLBACK, NONFINITE, OPTIMAL, OUTSIDE, PASS, REASONS, RULES, MarginField,
                   TableField, ValueFilter, smooth_rule, switch_rule)
from .wrapper import SafetyFilter

__all__ = ["AFTER_HORIZON", "BLEND", "FALLBACK", "MarginField", "NONFINITE", "OPTIMAL", "OUTSIDE", "PASS", "REASONS",
           "RULES", "SafetyFilter", "TableField", "ValueFilter", "smooth_rule", "switch_rule"]
