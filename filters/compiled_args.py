"""What the compiled decision reads, by name: the cells, the table, the control box's map, the verdict on one action and
the work space (:mod:`softreach.filters.compiled`, :mod:`softreach.filters.judge`); the model's side is
:class:`~softreach.reach.proof.period.Motion`. Each is a :class:`typing.NamedTuple`: a field read by name compiles as
one by position, and numba's cache finds the class again by its module. The compiled entry points take them as plain
tuples (:func:`plain`) and name them again first thing (:func:`named`, :func:`packed_space`): numba types a plain tuple
from a fingerprint computed in C, a named one field by field in Python (far slower), at every call. The work space goes
packed, as every array handed over is unboxed at every call."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.period import Motion


class Cells(NamedTuple):
    """The landing cells' kernel arguments and plans
    (:class:`~softreach.reach.proof.cell_certificate.CellCertificate`'s ``kernel_args`` and ``plan_args``)."""

    land: tuple
    plan: tuple


class TableArgs(NamedTuple):
    """A table's fields as the compiled code reads them (:func:`~softreach.reach.proof.lookahead.kernel_field`)."""

    #: ``W_eps`` over the state and the budget, or a budget surface's ``Q_min - z`` in its shape
    W: tuple
    #: the budget grid's top and bottom [s]
    z_top: float
    z_floor: float
    #: a budget surface's horizon, which caps the budget read at the time left, else ``+inf`` (``usable_budget``)
    z_left: float
    #: ``V`` (``W`` again where the table has none)
    V: tuple
    has_V: bool
    #: finite where a state lies on the table (:func:`~softreach.filters.judge.on_table`): ``W``, or a budget
    #: surface's before its nodes where no budget suffices are made infinite
    inside: tuple


class ActionMap(NamedTuple):
    """The control box, its map (:func:`~softreach.reach.proof.lookahead.action_map`) and the actions in it."""

    #: an environment applies ``mid + half * q``
    mid: np.ndarray
    half: np.ndarray
    #: the control box's corners
    lo: np.ndarray
    hi: np.ndarray
    #: the candidates normalised, each mapped back exactly (:func:`~softreach.reach.proof.lookahead.exact_normalized`)
    cands_q: np.ndarray
    #: the action where no candidate can be bounded (:attr:`ValueFilter.fallback_action`), and normalised alike
    fallback: np.ndarray
    fallback_q: np.ndarray


class Verdict(NamedTuple):
    """What :func:`~softreach.filters.judge.judge` finds of one held action without reading the table."""

    #: passes (keeps ``C1`` and the budget, ends in the landing cells); every run surely lands inside the period
    ok: bool
    lands: bool
    #: the enclosure is finite; ``C1`` kept, ending by the horizon; that and the budget kept
    bounded: bool
    in_c1: bool
    kept: bool
    #: the largest ``c1`` over the motion, the budget at the period's end, the period's end (at most the horizon)
    c1: float
    z_end: float
    t_next: float


class Work(NamedTuple):
    """One row's work space of the one-period test and the table's reads."""

    #: boxes of the period's whole motion, of part of it, and over the state and the budget
    tube_lo: np.ndarray
    tube_hi: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    #: a box's centre; a point over the state and the budget; the table's reads' scratch
    #: (:func:`~softreach.reach.proof.kernels.point_scratch`)
    centre: np.ndarray
    point: np.ndarray
    buf: np.ndarray
    node: np.ndarray


class Box(NamedTuple):
    """A box's lower and upper corners."""

    lo: np.ndarray
    hi: np.ndarray


class DecisionSpace(NamedTuple):
    """The work space of :func:`~softreach.filters.compiled.decide_rows`; ``c_*`` hold one entry per candidate."""

    work: Work
    #: the end box of a candidate judged from a whole end box (:func:`~softreach.filters.keeps.keeps`)
    work_box: Box
    #: the part of an end box that :func:`~softreach.filters.keeps.keeps` covers by one candidate (a slab)
    slab_box: Box
    #: ``(J + 1, n)``: each candidate's end box, and the policy's (or the bisection's) in the last row
    end_lo: np.ndarray
    end_hi: np.ndarray
    #: passes, next value, badness, end budget, keeps ``C1`` and the budget
    c_ok: np.ndarray
    c_next: np.ndarray
    c_bad: np.ndarray
    c_zend: np.ndarray
    c_kept: np.ndarray
    #: the normalised distance to the policy's action, the order of preference and its key
    c_dist: np.ndarray
    c_order: np.ndarray
    c_pref: np.ndarray
    #: the action being judged, and the normalised action whose image it is (where it is a candidate or a blend)
    act: np.ndarray
    act_q: np.ndarray
    #: the row's policy action as applied, and normalised (where the policy's actions are)
    pol: np.ndarray
    pol_q: np.ndarray
    #: the verdict's ``in_c1``, ``bounded`` and ``c1``
    c_in: np.ndarray
    c_bounded: np.ndarray
    c_c1: np.ndarray
    #: ``(8, n)``: the start-plan search's boxes
    boxes: np.ndarray


def plain(value: Any) -> Any:
    """``value`` with every tuple in it, named or not, a plain tuple: what the compiled entry points take."""
    return tuple(plain(v) for v in value) if isinstance(value, tuple) else value


@njit(inline="always")
def named(M, C, T, action):
    """The plain tuples of a :class:`~softreach.reach.proof.period.Motion`, :class:`Cells`, :class:`TableArgs` and
    :class:`ActionMap` named again."""
    return Motion(*M), Cells(*C), TableArgs(*T), ActionMap(*action)


#: rows of the packed arrays (:func:`packed_space`): floats and booleans per candidate, floats per state (and budget),
#: floats per action axis
N_FLOAT_J, N_BOOL_J, N_FLOAT_N, N_FLOAT_N1, N_FLOAT_M = 6, 4, 9, 3, 4


@njit(inline="always")
def packed_space(packed):
    """The :class:`DecisionSpace` whose arrays are views of the packed one
    (:func:`~softreach.filters.compiled.decision_space`), in Python and compiled alike."""
    fJ, bJ, fn, fn1, ends, act, order, boxes, buf, node = packed
    work = Work(fn[0], fn[1], fn[2], fn[3], fn1[0], fn1[1], fn[6], fn1[2], buf, node)
    return DecisionSpace(work, Box(fn[4], fn[5]), Box(fn[7], fn[8]), ends[0], ends[1], bJ[0], fJ[0], fJ[1], fJ[2],
                         bJ[1], fJ[3], order, fJ[4], act[0], act[1], act[2], act[3], bJ[2], bJ[3], fJ[5], boxes)
