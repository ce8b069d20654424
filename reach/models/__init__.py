"""Models: the paper's landings and the Dubins vehicle. ``get_model(name)`` builds one by short name or by
``"module:Class"`` path; the names, classes and environment ids live in :mod:`softreach.reach.registry`."""

from __future__ import annotations

from ..problem import Model
from ..registry import _LOADED as MODELS  # the classes imported so far, by short name
from ..registry import get_model, register_model
from .pointmass import PointMass, PointMassParams

register_model("pointmass", PointMass)


def model_from_metadata(meta: dict) -> Model:
    """Rebuild the model recorded in a table's metadata (JSON lists become tuples again): by its short name, or,
    for a model without one, by the ``"module:Class"`` path the table recorded."""
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in meta["parameters"].items()}
    return get_model(meta.get("class") or meta["name"], **params)


__all__ = ["model_from_metadata", "MODELS", "Model", "PointMass", "PointMassParams", "get_model", "register_model"]
