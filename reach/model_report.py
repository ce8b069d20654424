"""What plots and reports read of a model beside its dynamics and sets: a group of its own.

How the task is named (:class:`TaskWords`), the budgets whose sets the summaries show, the axes of the set panels,
the units of the inputs, and two facts about states that reports use (:meth:`ReportPart.sink_rate`,
:meth:`ReportPart.start_difficulty`). :class:`~softreach.reach.problem.Model` is a :class:`ReportPart`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from .dynamics import Array, Components


@dataclass(frozen=True)
class TaskWords:
    """How plots and reports name a model's task, so that a cruise controller is not said to "land".

    :param target: the target set's name in legends
    :param reached: what an episode that reaches the target did, in a sentence ("reached the target", "landed")
    :param success: the rate of such episodes ("success rate", "landing rate")
    :param duration: the time an episode took to reach the target ("time to target", "time to land")
    :param arrival_speed: the speed :meth:`Model.sink_rate` reports on arrival, ``None`` for a model without one
    """

    target: str = "target"
    reached: str = "reached the target"
    success: str = "success rate"
    duration: str = "time to target"
    arrival_speed: str | None = None


#: the words of the landing tasks (point mass, glider)
LANDING_WORDS = TaskWords(target="target (landing zone)", reached="landed", success="landing rate",
                          duration="time to land", arrival_speed="touchdown sink rate")


class ReportPart:
    """The part of a model that plots and reports read; see the module docstring."""

    #: how plots and reports name the task (:class:`TaskWords`)
    words: TaskWords = TaskWords()
    #: budgets [s] whose sets the summaries and plots show, and those of the paper's representative starts
    default_budgets: tuple[float, ...] = (0.0, 0.06, 0.3, 0.6)
    paper_budgets: tuple[float, ...] = (0.0, 0.3, 0.6)
    #: the ``(horizontal, vertical)`` state axes of the set panels of a model with more than two states
    plot_axes: tuple[int, int] = (1, 0)
    #: units of the control and of the disturbance components (messages, plots)
    control_units: tuple[str, ...] = ()
    disturbance_units: tuple[str, ...] = ()

    def sink_rate(self, x: Sequence[float]) -> float:
        """The speed at touchdown that an evaluation reports [m/s] (the landings: vertical speed downwards);
        ``nan`` for a model without one (the default).

        :param x: one state, a number per component
        """
        return math.nan

    def start_difficulty(self, x: Components) -> Array:
        """How hard a start is, for picking the paper's representative starts (:func:`softreach.agents.tables.
        paper_starts` takes the largest among deep nodes of each set). The landings: the altitude. The default:
        the first state component.

        :param x: state components (arrays over the grid)
        """
        return x[0]
