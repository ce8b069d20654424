"""Training speed of ``softreach train``: environment steps per second of PPO, with or without the safety filter.

Runs :func:`softreach.agents.train.train` as ``softreach train`` does and times every rollout after the first
(the first carries the one-time costs: imports, numba compiling the filter, loading its cells), by the process's
CPU time (what one idle core takes) and by the wall clock (what this machine took under its load)::

    OMP_NUM_THREADS=1 python benchmarks/train_speed.py                               # no filter
    OMP_NUM_THREADS=1 python benchmarks/train_speed.py --filter pointmass-held.srt   # under the filter
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from stable_baselines3.common.callbacks import BaseCallback


class RolloutClock(BaseCallback):
    """Records ``(steps, cpu seconds, wall seconds)`` at the end of every rollout."""

    def __init__(self) -> None:
        super().__init__()
        self.marks: list[tuple[int, float, float]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.marks.append((self.num_timesteps, time.process_time(), time.perf_counter()))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="pointmass")
    p.add_argument("--filter", default=None, help="table of the safety filter (default: none)")
    p.add_argument("--timesteps", type=int, default=20480)
    args = p.parse_args(argv)

    from softreach.agents.train import TrainSpec, train

    clock = RolloutClock()
    with tempfile.TemporaryDirectory() as out:
        spec = TrainSpec(model=args.model, filter=args.filter, timesteps=args.timesteps, out=out, progress=False,
                         run_overrides={"eval_freq": 0})
        train(spec, callbacks=[clock])
    (s0, c0, w0), (s1, c1, w1) = clock.marks[0], clock.marks[-1]
    steps = s1 - s0
    print(f"{args.model}, filter {args.filter or 'none'}: {steps} steps after the first rollout in {c1 - c0:.1f} s "
          f"of CPU ({steps / (c1 - c0):,.0f} steps/s) and {w1 - w0:.1f} s of wall clock ({steps / (w1 - w0):,.0f} "
          f"steps/s; load average {os.getloadavg()[0]:.1f}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')})")


if __name__ == "__main__":
    main()
