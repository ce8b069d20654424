"""The one registry of models: short name <-> model class <-> Gymnasium env id <-> command-line choice.

A model is named on the command line and in code in one of two ways:

* a **short name** registered here (``pointmass``, ``glider``, ``dubins``, or one added with
  :func:`register_model`);
* a **class path** ``"package.module:ClassName"`` of any :class:`~softreach.reach.problem.Model` subclass that
  Python can import, so that a user's own system needs no softreach file edited::

      softreach solve my_pkg.my_mod:MyModel

Built-in models are listed by class path and imported only when first asked for (the glider's module is not
imported by ``softreach --help`` or by a point-mass solve). A table records the class path of a model that has
no short name (:meth:`Model.metadata`), so :func:`model_from_metadata` can rebuild it.

Every model has an environment: the two landing envs of the paper have their own ids; every other model runs in
the generic :data:`GENERIC_ENV_ID` (``gymnasium.make(GENERIC_ENV_ID, model=MyModel())``), built from what the
model declares (:class:`~softreach.envs.softreach_env.SoftReachEnv`).
"""

from __future__ import annotations

import argparse
import importlib
from dataclasses import dataclass
from typing import Any

#: the generic environment of any model (:class:`softreach.envs.softreach_env.SoftReachEnv`)
GENERIC_ENV_ID = "softreach/SoftReach-v0"


@dataclass(frozen=True)
class ModelEntry:
    """One registered model.

    :param name: the short name (command-line choice, table metadata ``name``)
    :param target: ``"module:Class"`` to import it from
    :param env_id: its Gymnasium environment id
    """

    name: str
    target: str
    env_id: str = GENERIC_ENV_ID


_ENTRIES: dict[str, ModelEntry] = {
    "pointmass": ModelEntry("pointmass", "softreach.reach.models.pointmass:PointMass", "softreach/PointMassLanding-v0"),
    "glider": ModelEntry("glider", "softreach.reach.models.glider:Glider", "softreach/GliderLanding-v0"),
    "dubins": ModelEntry("dubins", "softreach.reach.models.dubins:Dubins"),
}
#: classes already imported, by short name (the ``MODELS`` of :mod:`softreach.reach.models`)
_LOADED: dict[str, type] = {}


def register_model(name: str, cls: type | str, env_id: str = GENERIC_ENV_ID) -> None:
    """Make a model available under a short name to :func:`get_model`, the command line and the agents.

    :param name: the short name (letters, digits, ``_`` and ``-``; no ``:``, which marks a class path)
    :param cls: the :class:`~softreach.reach.problem.Model` subclass, or its ``"module:Class"`` path
    :param env_id: its Gymnasium id (default: the generic :data:`GENERIC_ENV_ID`)
    """
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-" for c in name):
        raise ValueError(f"a model name is made of letters, digits, '_' and '-', got {name!r}")
    if isinstance(cls, str):
        _split(cls)
        target = cls
    else:
        _check_model_class(cls, name)
        target = f"{cls.__module__}:{cls.__qualname__}"
        _LOADED[name] = cls
    old = _ENTRIES.get(name)
    _ENTRIES[name] = ModelEntry(name, target, env_id if old is None or env_id != GENERIC_ENV_ID else old.env_id)


def model_names() -> list[str]:
    """The registered short names, sorted: the command line's choices."""
    return sorted(_ENTRIES)


def env_ids() -> dict[str, str]:
    """Short name -> Gymnasium id, for every registered model."""
    return {name: entry.env_id for name, entry in sorted(_ENTRIES.items())}


def is_class_path(spec: str) -> bool:
    """Whether ``spec`` names a model by ``"module:Class"`` rather than by a short name."""
    return ":" in spec


def model_class(spec: str) -> type:
    """The model class of a short name or a ``"module:Class"`` path.

    :raises ValueError: an unknown name, a module that does not import or a class that is not a Model (the
        message names the value)
    """
    if not isinstance(spec, str):
        raise ValueError(f"a model is named by a string (short name or 'module:Class'), got {spec!r}")
    if spec in _LOADED:
        return _LOADED[spec]
    entry = _ENTRIES.get(spec)
    if entry is None and not is_class_path(spec):
        raise ValueError(f"unknown model {spec!r}; choose from {model_names()} or give 'module:Class'")
    module_name, class_name = _split(entry.target if entry else spec)
    try:
        module = _import(module_name, user=entry is None)
    except ImportError as exc:
        where = " (searched the Python path and the current directory)" if entry is None else ""
        raise ValueError(f"model {spec!r}: cannot import module {module_name!r}{where} ({exc})") from None
    cls: Any = module
    for part in class_name.split("."):
        cls = getattr(cls, part, None)
        if cls is None:
            raise ValueError(f"model {spec!r}: module {module_name!r} has no {class_name!r}")
    _check_model_class(cls, spec)
    if entry is not None:
        _LOADED[spec] = cls
    return cls


def get_model(spec: str, **params: Any):
    """Build a model by short name or ``"module:Class"``, with optional parameter overrides.

    :param spec: ``"pointmass"``, ``"glider"``, ``"dubins"``, a registered name or ``"module:Class"``
    :param params: keyword arguments of the model's constructor
    """
    return model_class(spec)(**params)


def env_id(spec: str) -> str:
    """The Gymnasium id of a model's environment (the generic one for every model without its own)."""
    entry = _ENTRIES.get(spec)
    if entry is None:
        model_class(spec)  # an unknown name or a bad class path fails here, naming it
        return GENERIC_ENV_ID
    return entry.env_id


def spec_of(model: Any) -> str:
    """How a model object is named: its short name if its class is registered under it, else ``"module:Class"``."""
    cls = type(model)
    name = getattr(model, "name", None)
    entry = _ENTRIES.get(name) if isinstance(name, str) else None
    path = f"{cls.__module__}:{cls.__qualname__}"
    if entry is not None and (_LOADED.get(name) is cls or entry.target == path):
        return name
    return path


def make_env(spec: str | Any, **kwargs: Any):
    """``gymnasium.make`` of a model's environment: its own id, or the generic env with the model passed in.

    :param spec: a short name or ``"module:Class"`` path (the model's own env id), or a model object (the
        generic env)
    :param kwargs: the environment's keyword arguments
    """
    import gymnasium as gym

    import softreach.envs  # noqa: F401  (registers the ids)

    if isinstance(spec, str):
        eid = env_id(spec)
        if eid == GENERIC_ENV_ID:
            kwargs = {"model": get_model(spec), **kwargs}
        return gym.make(eid, **kwargs)
    # a model object (perhaps with its own parameters) runs in the generic env, which takes it as it is
    return gym.make(GENERIC_ENV_ID, model=spec, **kwargs)


def model_argument(text: str) -> str:
    """``argparse`` type of a model argument: a registered short name or an importable ``"module:Class"``."""
    try:
        model_class(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def model_metavar() -> str:
    """``{pointmass,glider,...}|module:Class``: what a model argument accepts, for ``--help``."""
    return "{" + ",".join(model_names()) + "}|module:Class"


def _import(module_name: str, user: bool):
    """Import ``module_name``; for a user's class path (``user``) the current directory is searched too, after
    the Python path: the ``softreach`` console script, unlike ``python -m``, does not put it on ``sys.path``, and
    a table that records ``"acc:ACC"`` must be usable from the folder holding ``acc.py`` without ``PYTHONPATH``."""
    import os
    import sys

    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        top = module_name.partition(".")[0]
        cwd = os.getcwd()
        # only a missing top-level module is looked for in the current directory, not an import error inside it
        if not user or exc.name != top or any(p in ("", cwd) or os.path.abspath(p) == cwd for p in sys.path):
            raise
        sys.path.append(cwd)
        importlib.invalidate_caches()
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError as again:
            sys.path.remove(cwd)
            raise again from None


def _split(target: str) -> tuple[str, str]:
    module_name, sep, class_name = target.partition(":")
    if not sep or not module_name or not class_name:
        raise ValueError(f"a model class path is 'package.module:ClassName', got {target!r}")
    return module_name, class_name


def _check_model_class(cls: Any, spec: str) -> None:
    from .problem import Model

    if not (isinstance(cls, type) and issubclass(cls, Model)):
        raise ValueError(f"model {spec!r} is {cls!r}, not a subclass of softreach.reach.problem.Model")


__all__ = ["GENERIC_ENV_ID", "ModelEntry", "env_id", "env_ids", "get_model", "is_class_path", "make_env", "model_argument",
           "model_class", "model_metavar", "model_names", "register_model", "spec_of"]
