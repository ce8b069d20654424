"""Pointwise expressions recorded from the solver's own array code, for :mod:`softreach.reach.numerics.fused`.

The derivative schemes, a model's Hamiltonian and dissipation, the projection and the Runge-Kutta stages are written
once, against arrays (:mod:`softreach.reach.backend`). Run on :class:`Sym` placeholders instead of arrays, the same
code records each operation as one line of straight-line Python (``t12 = max(t10, t11)``), which
:mod:`softreach.reach.numerics.fused` compiles into one loop over the grid. Whatever the code does that a pointwise loop
cannot (a Python branch on a value, a reduction, a foreign array, a function not listed here) raises
:class:`Unsupported`, and the solver keeps its array path.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class Unsupported(Exception):
    """The code asked for something a pointwise kernel cannot do."""


class _Missing(Unsupported, AttributeError):
    """An array method a placeholder does not have (an ``AttributeError`` too, so that ``hasattr`` says no)."""


#: numpy ufuncs a kernel line can spell, as ``name -> format`` of their arguments
_UFUNCS = {
    "add": "({0} + {1})", "subtract": "({0} - {1})", "multiply": "({0} * {1})", "true_divide": "({0} / {1})",
    "divide": "({0} / {1})", "negative": "(-{0})", "positive": "(+{0})", "absolute": "abs({0})",
    "fabs": "abs({0})", "maximum": "max({0}, {1})", "minimum": "min({0}, {1})", "fmax": "max({0}, {1})",
    "fmin": "min({0}, {1})", "sin": "np.sin({0})", "cos": "np.cos({0})", "tan": "np.tan({0})",
    "arcsin": "np.arcsin({0})", "arccos": "np.arccos({0})", "arctan": "np.arctan({0})",
    "arctan2": "np.arctan2({0}, {1})", "exp": "np.exp({0})", "log": "np.log({0})", "sqrt": "np.sqrt({0})",
    "tanh": "np.tanh({0})", "floor": "np.floor({0})", "ceil": "np.ceil({0})", "sign": "np.sign({0})",
    "square": "({0} * {0})", "hypot": "np.hypot({0}, {1})", "power": "({0} ** {1})",
    "clip": "min(max({0}, {1}), {2})",
}
_COMPARE = {"less": "<", "less_equal": "<=", "greater": ">", "greater_equal": ">=", "equal": "==", "not_equal": "!="}
_LOGIC = {"logical_and": "({0} & {1})", "logical_or": "({0} | {1})", "logical_not": "(not {0})"}


class Tape:
    """The lines recorded so far; ``const`` spells a number in the kernel's float type."""

    def __init__(self, const: str = "F"):
        self.lines: list[str] = []
        self.const = const
        self._n = 0

    def var(self, name: str, kind: str = "f") -> "Sym":
        """A kernel input named ``name``."""
        return Sym(self, name, kind)

    def emit(self, expr: str, kind: str = "f") -> "Sym":
        name = f"t{self._n}"
        self._n += 1
        self.lines.append(f"{name} = {expr}")
        return Sym(self, name, kind)

    def spell(self, v: Any) -> str:
        """An operand as kernel code: a placeholder's name, or a number as a literal of the kernel's type."""
        if isinstance(v, Sym):
            if v.tape is not self:
                raise Unsupported("a value from another trace")
            return v.name
        if isinstance(v, (bool, np.bool_)):
            return "True" if v else "False"
        if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
            x = float(v)
            if math.isnan(x):
                return f"{self.const}(np.nan)"
            if math.isinf(x):
                return f"{self.const}({'' if x > 0 else '-'}np.inf)"
            return f"{self.const}({x!r})"
        raise Unsupported(f"an operand of type {type(v).__name__}")

    def value(self, v: Any) -> str:
        """The kernel code of a result that may be a placeholder or a plain number."""
        return self.spell(v)


class Sym:
    """A placeholder for one node's value of an array (``kind`` ``"f"``: a float, ``"b"``: a bool).

    It has a ``shape`` so that code which tells arrays from numbers (``hasattr(v, "shape")``) takes the array
    branch; it refuses ``bool()``/``float()``, which would make the kernel depend on one node's value.
    """

    __array_priority__ = 1000
    shape = ()

    def __init__(self, tape: Tape, name: str, kind: str = "f"):
        self.tape, self.name, self.kind = tape, name, kind

    def _op(self, fmt: str, *args: Any, kind: str = "f") -> "Sym":
        return self.tape.emit(fmt.format(*(self.tape.spell(a) for a in args)), kind)

    def __add__(self, o): return self._op("({0} + {1})", self, o)
    def __radd__(self, o): return self._op("({0} + {1})", o, self)
    def __sub__(self, o): return self._op("({0} - {1})", self, o)
    def __rsub__(self, o): return self._op("({0} - {1})", o, self)
    def __mul__(self, o): return self._op("({0} * {1})", self, o)
    def __rmul__(self, o): return self._op("({0} * {1})", o, self)
    def __truediv__(self, o): return self._op("({0} / {1})", self, o)
    def __rtruediv__(self, o): return self._op("({0} / {1})", o, self)
    def __neg__(self): return self._op("(-{0})", self)
    def __pos__(self): return self
    def __abs__(self): return self._op("abs({0})", self)
    def __lt__(self, o): return self._op("({0} < {1})", self, o, kind="b")
    def __le__(self, o): return self._op("({0} <= {1})", self, o, kind="b")
    def __gt__(self, o): return self._op("({0} > {1})", self, o, kind="b")
    def __ge__(self, o): return self._op("({0} >= {1})", self, o, kind="b")

    def __pow__(self, o):
        if isinstance(o, (int, np.integer)) and o == 2:
            return self._op("({0} * {0})", self)
        return self._op("({0} ** {1})", self, o)

    def _logic(self, o, sym):
        if self.kind != "b" or (isinstance(o, Sym) and o.kind != "b"):
            raise Unsupported(f"bitwise {sym} of numbers")
        return self._op("({0} " + sym + " {1})", self, o, kind="b")

    def __and__(self, o): return self._logic(o, "&")
    def __rand__(self, o): return self._logic(o, "&")
    def __or__(self, o): return self._logic(o, "|")
    def __ror__(self, o): return self._logic(o, "|")

    def __invert__(self):
        if self.kind != "b":
            raise Unsupported("~ of a number")
        return self._op("(not {0})", self, kind="b")

    def __bool__(self):
        raise Unsupported("a Python branch on a node's value")

    def __float__(self):
        raise Unsupported("float() of a node's value")

    __int__ = __index__ = __float__
    __hash__ = object.__hash__

    def __getattr__(self, name: str):
        # an array method (``.max()``, ``.all()``, ``.sum()``) reduces or inspects the grid: not pointwise
        if name.startswith("__"):
            raise AttributeError(name)
        raise _Missing(f"the array method .{name}")

    def __eq__(self, o):  # noqa: D105 - elementwise, as arrays
        return self._op("({0} == {1})", self, o, kind="b")

    def __ne__(self, o):
        return self._op("({0} != {1})", self, o, kind="b")

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs:
            raise Unsupported(f"numpy.{ufunc.__name__}.{method} with {sorted(kwargs)}")
        name = ufunc.__name__
        if name in _UFUNCS:
            if name == "power" and isinstance(inputs[1], (int, np.integer)) and inputs[1] == 2:
                return self._op("({0} * {0})", inputs[0])
            return self._op(_UFUNCS[name], *inputs)
        if name in _COMPARE:
            return self._op("({0} " + _COMPARE[name] + " {1})", *inputs, kind="b")
        if name in _LOGIC:
            return self._op(_LOGIC[name], *inputs, kind="b")
        raise Unsupported(f"numpy.{name}")

    def __array_function__(self, func, types, args, kwargs):
        if func is np.where and len(args) == 3 and not kwargs:
            c, a, b = args
            return self._op("({1} if {0} else {2})", c, a, b)
        if func is np.clip and len(args) == 3 and not kwargs:
            return self._op("min(max({0}, {1}), {2})", *args)
        if func in (np.maximum, np.minimum, np.abs):
            return self.__array_ufunc__(func, "__call__", *args, **kwargs)
        raise Unsupported(f"numpy.{getattr(func, '__name__', func)}")
