"""The cart of docs/models.md for the tests: :func:`doc_cart` is the page's ``cart.py`` itself (its dynamics, sets,
motion bound and environment defaults: the one copy of its ``held_box_kernel``), and :class:`CartMotion` its
motion and sets alone, for the tests that declare their own variant of the cart (its boxes, grid and period, or
no motion bound) around them."""

from __future__ import annotations

import re
import sys
import types
from functools import lru_cache
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "models.md"
#: the module name the page's ``cart.py`` is loaded under (not ``cart``, which the doc tests write and import)
MODULE = "docs_models_cart"


def doc_cart_source() -> str:
    """The ``cart.py`` code block of docs/models.md (the ``python`` block whose first line is ``# cart.py``)."""
    for block in re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S):
        if block.startswith("# cart.py\n"):
            return block
    raise AssertionError(f"{DOC}: no python block starting with '# cart.py'")


@lru_cache(maxsize=None)
def doc_cart() -> types.ModuleType:
    """The page's ``cart.py`` as a module (:data:`MODULE`), loaded once per process."""
    module = types.ModuleType(MODULE)
    module.__file__ = str(DOC)
    sys.modules[MODULE] = module
    exec(compile(doc_cart_source(), f"{DOC}:cart.py", "exec"), module.__dict__)
    return module


_Cart = doc_cart().Cart


class CartMotion:
    """The page's ``p' = v``, ``v' = a + w``; target ``|p|, |v| <= 0.2``, ``C1 = {|p|, |v| <= 2}``,
    ``C2 = {|v| <= 1}``: its names, horizon, domain, set boxes and functions, without its motion bound."""

    name = _Cart.name
    state_names = _Cart.state_names
    state_units = _Cart.state_units
    horizon = _Cart.horizon
    domain = _Cart.domain
    hard_box = _Cart.hard_box
    target_box = _Cart.target_box
    soft_box = _Cart.soft_box
    drift = _Cart.drift
    control_matrix = _Cart.control_matrix
    disturbance_matrix = _Cart.disturbance_matrix
    target = _Cart.target
    hard_constraint = _Cart.hard_constraint
    soft_constraint = _Cart.soft_constraint
