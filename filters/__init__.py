"""softreach.filters: a least-restrictive safety filter on a ``W_eps`` table (paper §V; docs/filters.md): the batched
core :class:`ValueFilter`, the ``gymnasium.Wrapper`` :class:`SafetyFilter`, and :class:`VecSafetyFilter` for SB3.

Each name loads at its first use: the ``softreach`` command line, which registers ``compile`` from :mod:`.precompile`,
imports no filter code it does not run, and a process that filters imports no torch (:class:`VecSafetyFilter` does,
through stable-baselines3)."""

import importlib
from typing import Any

#: public name -> the module defining it
_EXPORTS = {**{name: ".core" for name in ("AFTER_HORIZON", "BLEND", "CERTIFY_REASONS", "FALLBACK", "NO_PLAN",
                                          "OPTIMAL", "OUTSIDE", "PASS", "PLAN_LAND", "PLAN_SAFE", "REASONS", "RULES",
                                          "UNCERTIFIED", "ValueFilter")},
            "Lookahead": "softreach.reach.proof.lookahead", "TableField": "softreach.reach.tables.field",
            "SafetyFilter": ".wrapper", "VecSafetyFilter": ".vector"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
