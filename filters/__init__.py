"""softreach.filters: a least-restrictive safety filter on a ``W_eps`` table (paper §V; docs/filters.md): the batched
core :class:`ValueFilter`, the ``gymnasium.Wrapper`` :class:`SafetyFilter`, and :class:`VecSafetyFilter` for SB3.

Each name loads at its first use: the ``softreach`` command line, which registers ``compile`` from :mod:`.precompile`,
imports no filter code it does not run, and a process that filters imports no torch (:class:`VecSafetyFilter` does,
through stable-baselines3)."""

from softreach import lazy_exports

#: public name -> the module defining it
_EXPORTS = {**{name: ".core" for name in ("AFTER_HORIZON", "BLEND", "CERTIFY_REASONS", "FALLBACK", "NO_PLAN",
                                          "OPTIMAL", "OUTSIDE", "PASS", "PLAN_LAND", "PLAN_SAFE", "REASONS", "RULES",
                                          "UNCERTIFIED", "ValueFilter")},
            "Lookahead": "softreach.reach.proof.lookahead", "TableField": "softreach.reach.tables.field",
            "SafetyFilter": ".wrapper", "VecSafetyFilter": ".vector"}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
