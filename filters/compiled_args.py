"""What the compiled decision reads, by name: the cells, the table, the control box's map, the verdict on one action
and the work space (:mod:`softreach.filters.compiled`, :mod:`softreach.filters.judge`); the model's side of the
one-period test, :class:`~softreach.reach.proof.period.Motion`, is the period's bounds' own.

Each is a :class:`typing.NamedTuple`: numba compiles a field read by name to the same code as one by position, and
keeps caching the functions that take them (their type names the class, which is found again by its module).

The compiled entry points (:func:`~softreach.filters.compiled.decide_rows`, :func:`~softreach.filters.
compiled_certify.certify_rows`, :func:`~softreach.filters.compiled_starts.start_plan_rows`) take them as plain
tuples (:func:`plain`) and name them again first thing (:func:`named`, :func:`packed_space`): numba types a plain
tuple of arrays at each call from a fingerprint computed in C, a named tuple in Python, field by field, which would
double the fixed cost of a one-row decision. Each array a call hands over is unboxed again at every call, so the
work space goes packed, its arrays of one kind rows of one array (:func:`packed_space`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.period import Motion


class Cells(NamedTuple):
    """The cells the decision uses (:class:`~softreach.reach.proof.cell_certificate.CellCertificate`'s kernel
    arguments)."""

    #: the safe cells' kernel arguments (the landing cells' where there are no safe cells: then unused)
    safe: tuple
    #: whether there are safe cells
    has_safe: bool
    #: the landing cells' kernel arguments
    land: tuple
    #: the safe cells' plans (``plan_args``; the landing cells' where there are no safe cells)
    safe_plan: tuple
    #: the landing cells' plans
    land_plan: tuple


class TableArgs(NamedTuple):
    """A table's fields as the compiled code reads them (:func:`~softreach.reach.proof.kernels.certificate_row`,
    :func:`~softreach.reach.proof.box_max.kernel_field`, :attr:`~softreach.reach.proof.lookahead.Lookahead.
    table_args`)."""

    #: ``W_eps`` over the state and the budget, or a budget surface's ``Q_min - z`` in its shape
    W: tuple
    #: the budget grid's top and bottom [s]
    z_top: float
    z_floor: float
    #: the horizon where the budget read is at most the time left (a budget surface), else ``+inf``
    #: (:func:`~softreach.reach.proof.kernels.usable_budget`)
    z_left: float
    #: ``V`` (``W`` again where the table has none)
    V: tuple
    has_V: bool
    #: the safe value ``V_safe`` (``V`` again where the table has none)
    S: tuple
    has_S: bool
    #: the field whose finite values say where a state lies on the table (:func:`~softreach.filters.judge.on_table`):
    #: ``W`` itself, or a budget surface's before its nodes where no budget suffices are made infinite
    inside: tuple


class ActionMap(NamedTuple):
    """The control box's map (:func:`~softreach.reach.proof.lookahead.action_map`) and the candidates in it."""

    #: the control box's centre and half-width: an environment applies ``mid + half * q``
    mid: np.ndarray
    half: np.ndarray
    #: the candidates normalised, each mapped back exactly (:func:`~softreach.reach.proof.lookahead.exact_normalized`)
    cands_q: np.ndarray


class Verdict(NamedTuple):
    """What :func:`~softreach.filters.judge.judge` finds of one held action without reading the table."""

    #: the action passes: its period keeps ``C1`` and the budget and its end box lies in the landing cells
    ok: bool
    #: every run surely lands inside the period
    lands: bool
    #: the enclosure bounds the motion (finite boxes)
    bounded: bool
    #: the motion keeps ``C1`` and the period ends by the horizon
    in_c1: bool
    #: ``in_c1`` and the budget is kept
    kept: bool
    #: its end keeps inside the safe cells
    proven: bool
    #: the largest ``c1`` over the motion
    c1: float
    #: the budget at the period's end
    z_end: float
    #: the period's end, at most the horizon
    t_next: float


class Work(NamedTuple):
    """One row's work space of the one-period test and the table's reads."""

    #: the box of the period's whole motion
    tube_lo: np.ndarray
    tube_hi: np.ndarray
    #: a box of part of the motion
    lo: np.ndarray
    hi: np.ndarray
    #: a box over the state and the budget (one longer than the state)
    box_lo: np.ndarray
    box_hi: np.ndarray
    #: the box maximum's scratch for ``W_eps`` (over the state and the budget) and ``V`` / ``V_safe``
    #: (:func:`~softreach.reach.proof.kernels.box_scratch`)
    scratch_W: tuple
    scratch_V: tuple


class Box(NamedTuple):
    """A box's lower and upper corners."""

    lo: np.ndarray
    hi: np.ndarray


class DecisionSpace(NamedTuple):
    """The work space of :func:`~softreach.filters.compiled.decide_rows`: the compiled loops allocate nothing.
    ``c_*`` hold one entry per candidate."""

    work: Work
    #: the end box of a candidate judged from a whole end box (:func:`~softreach.filters.keeps.keeps`)
    work_box: Box
    #: ``(J + 1, n)``: each candidate's end box, and the policy's (or the bisection's) in the last row
    end_lo: np.ndarray
    end_hi: np.ndarray
    #: passes, its next value, its badness, its end budget, whether it keeps ``C1`` and the budget
    c_ok: np.ndarray
    c_next: np.ndarray
    c_bad: np.ndarray
    c_zend: np.ndarray
    c_kept: np.ndarray
    #: the rule's score, the normalised distance to the policy's action, the order of preference's key
    c_score: np.ndarray
    c_dist: np.ndarray
    c_pref: np.ndarray
    #: the action being judged
    act: np.ndarray
    #: a point over the state and the budget
    point: np.ndarray
    #: the verdict's ``in_c1``, ``bounded``, ``proven`` and ``c1``
    c_in: np.ndarray
    c_bounded: np.ndarray
    c_proven: np.ndarray
    c_c1: np.ndarray
    #: candidates whose next value is to be read; lower bounds; ties; the order of preference
    c_pick: np.ndarray
    c_low: np.ndarray
    c_tie: np.ndarray
    c_order: np.ndarray
    #: ``(8, n)``: the start-plan search's boxes (:func:`~softreach.filters.compiled_starts.start_plan_rows`)
    boxes: np.ndarray


def plain(value: Any) -> Any:
    """``value`` with every tuple in it, named or not, a plain tuple: what the compiled entry points take."""
    return tuple(plain(v) for v in value) if isinstance(value, tuple) else value


@njit(inline="always")
def named(M, C, T, action):
    """The plain tuples of a :class:`~softreach.reach.proof.period.Motion`, :class:`Cells`, :class:`TableArgs` and
    :class:`ActionMap` named again."""
    return Motion(*M), Cells(*C), TableArgs(*T), ActionMap(*action)


#: rows of the packed work space's arrays (:func:`packed_space`): one float and one boolean per candidate, floats
#: per state axis, floats per state axis and the budget
N_FLOAT_J, N_BOOL_J, N_FLOAT_N, N_FLOAT_N1 = 9, 6, 6, 3


@njit(inline="always")
def packed_space(packed):
    """The :class:`DecisionSpace` whose arrays are views of the packed one: ``(floats (N_FLOAT_J, J), booleans
    (N_BOOL_J, J), floats (N_FLOAT_N, n), floats (N_FLOAT_N1, n + 1), end boxes (2, J + 1, n), act, c_order, boxes,
    scratch_W, scratch_V)`` (:func:`~softreach.filters.compiled.decision_space`). In Python and compiled alike."""
    fJ, bJ, fn, fn1, ends, act, order, boxes, scratch_W, scratch_V = packed
    work = Work(fn[0], fn[1], fn[2], fn[3], fn1[0], fn1[1], scratch_W, scratch_V)
    return DecisionSpace(work, Box(fn[4], fn[5]), ends[0], ends[1], bJ[0], fJ[0], fJ[1], fJ[2], bJ[1], fJ[3], fJ[4],
                         fJ[5], act, fn1[2], bJ[2], bJ[3], bJ[4], fJ[6], bJ[5], fJ[7], fJ[8], order, boxes)
