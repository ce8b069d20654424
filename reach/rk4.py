"""The classical Runge-Kutta (RK4) step of softreach, written out for ``n`` state components.

The step's lines (:data:`RK4_LINES`) are written once, for any number of components, and compiled into each
function that takes the step (:func:`written_out`): the step itself (:func:`rk4_step`, used on Python floats
for one state and on numpy component arrays for ``N`` states), and the environments' scalar period loop
(:mod:`softreach.reach.integrator`), which takes the step without a call per sub-step. Written out, a step
costs no loop over the components; in a period loop, no call either (a call per sub-step is a twentieth of an
environment step, a loop over components half of it).
"""

from __future__ import annotations

import linecache
import textwrap
from collections.abc import Callable, Sequence
from typing import Any

#: the RK4 step's lines, for ``n`` components: from ``xc`` at ``tc`` to ``xn`` at ``te`` through the stage states
#: ``x2``, ``x3``, ``x4`` (``f`` at ``tm``, ``tm``, ``te``), with ``hh = hs / 2`` and ``h6 = hs / 6``
RK4_LINES = """\
{ys}, = xc
k1 = f(tc, xc, a, b)
x2 = [{x2}]
k2 = f(tm, x2, a, b)
x3 = [{x3}]
k3 = f(tm, x3, a, b)
x4 = [{x4}]
k4 = f(te, x4, a, b)
xn = [{xn}]"""

_RK4_STEP = """\
def rk4_step(f, tc, tm, te, hh, hs, h6, xc, a, b):
    {rk4}
    return xn, x2, x3, x4
"""

_COMPILED: dict[tuple[str, int], Callable] = {}


def written_out(template: str, n: int, namespace: dict[str, Any] | None = None) -> Callable:
    """The function defined by ``template`` with :data:`RK4_LINES` for ``n`` components written into it where it
    says ``{rk4}`` (compiled once; its source is kept for tracebacks).

    :param template: the source of one function, ``def name(...):``, with ``{rk4}`` on a line of its own
        (indented as the lines should be; other braces doubled)
    :param n: the number of state components
    :param namespace: the globals the function uses
    """
    key = (template, n)
    out = _COMPILED.get(key)
    if out is not None:
        return out
    c = range(n)

    def each(expr: str) -> str:
        return ", ".join(expr.format(i=i) for i in c)

    lines = RK4_LINES.format(ys=each("y{i}"), x2=each("y{i} + hh * k1[{i}]"), x3=each("y{i} + hh * k2[{i}]"),
                             x4=each("y{i} + hs * k3[{i}]"),
                             xn=each("y{i} + h6 * (k1[{i}] + 2.0 * k2[{i}] + 2.0 * k3[{i}] + k4[{i}])"))
    at = template.index("{rk4}")
    depth = at - template.rindex("\n", 0, at) - 1
    source = template.replace(" " * depth + "{rk4}", textwrap.indent(lines, " " * depth)).replace("{{", "{").replace(
        "}}", "}")
    function = template.split("(")[0].split()[-1]
    name = f"<softreach {function} for {n} components>"
    linecache.cache[name] = (len(source), None, source.splitlines(True), name)
    scope = dict(namespace or {})
    exec(compile(source, name, "exec"), scope)
    out = _COMPILED[key] = scope[function]
    return out


def rk4_step(n: int) -> Callable:
    """The classical RK4 step of ``x' = f(t, x, a, b)`` for ``n`` components, with ``a`` and ``b`` held.

    The returned ``rk4_step(f, tc, tm, te, hh, hs, h6, xc, a, b) -> (x_end, x2, x3, x4)`` takes the step's start
    ``tc``, its middle ``tm = tc + hh`` and end ``te = tc + hs``, ``hh = hs / 2`` and ``h6 = hs / 6`` (a period's
    loop knows them already), and one float or one array per component (``xc``, ``a``, ``b``: sequences of them;
    ``f`` returns a sequence). It gives the state at ``te`` and the stage states ``xc + hh k1``, ``xc + hh k2``,
    ``xc + hs k3`` (where RK4 evaluates ``f`` at ``tm``, ``tm``, ``te``; the budget evaluates ``h_eps`` there
    too). Its lines (:data:`RK4_LINES`) are written out for ``n`` components: a Python loop over the components
    would cost the environments about half their step.

    :param n: the number of state components
    """
    return written_out(_RK4_STEP, n)


def rk4_stages(f: Callable, t: float, x: Sequence[Any], a: Sequence[Any], b: Sequence[Any],
               h: float) -> tuple[list[Any], list[list[Any]]]:
    """One RK4 step (:func:`rk4_step`): the state at ``t + h`` and the four stage states
    ``[x, x + h/2 k1, x + h/2 k2, x + h k3]``.

    :param f: the vector field ``f(t, x, a, b)``, one float or array per component in and out
    :param t: start time [s]
    :param x: start state; ``a``: control; ``b``: disturbance (physical units, one float or array per component)
    :param h: step length [s]
    """
    xn, x2, x3, x4 = rk4_step(len(x))(f, t, t + 0.5 * h, t + h, 0.5 * h, h, h / 6.0, x, a, b)
    return xn, [list(x), x2, x3, x4]
