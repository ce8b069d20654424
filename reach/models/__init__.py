"""Models of the paper's landings. ``get_model(name)`` builds one by name."""

from __future__ import annotations

from ..problem import Model
from .pointmass import PointMass, PointMassParams

MODELS = {"pointmass": PointMass}


def register_model(name: str, cls: type) -> None:
    """Make a model class available to :func:`get_model` and the command line under ``name``."""
    MODELS[name] = cls


def get_model(name: str, **params) -> Model:
    """Build a model by name (``"pointmass"``, ``"glider"``) with optional parameter overrides."""
    if name == "glider" and "glider" not in MODELS:
        from . import glider  # noqa: F401  (registers itself)
    try:
        cls = MODELS[name]
    except KeyError:
        raise ValueError(f"unknown model {name!r}; known: {sorted(set(MODELS) | {'glider'})}") from None
    return cls(**params)


def model_from_metadata(meta: dict) -> Model:
    """Rebuild the model recorded in a table's metadata (JSON lists become tuples again)."""
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in meta["parameters"].items()}
    return get_model(meta["name"], **params)


__all__ = ["model_from_metadata", "MODELS", "PointMass", "PointMassParams", "get_model", "register_model"]
