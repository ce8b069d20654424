"""Training callbacks: periodic evaluation of the deployed policy (with the safety filter) that also records how
often the filter had to act, so the learning curves show the filter's share of the work; and the progress bar."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stable_baselines3.common.callbacks import EvalCallback


class FilterEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` (mean return, ``best_model.zip``), plus the share of evaluation steps in which the
    safety filter replaced the policy's action (``info["filter_active"]``), written beside the evaluations to
    ``eval/interventions.npz`` (``timesteps``, ``intervention_rate``) and logged as ``eval/intervention_rate``.

    The best checkpoint is the one with the highest mean evaluation return of the deployed closed loop; a hard
    violation costs 100 of it, a landing earns 100, so the criterion counts safety and the task together.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._steps = 0
        self._active = 0
        self.intervention_timesteps: list[int] = []
        self.intervention_rates: list[float] = []

    def _log_success_callback(self, locals_, globals_) -> None:
        super()._log_success_callback(locals_, globals_)
        self._steps += 1
        self._active += int(bool(locals_["info"].get("filter_active", False)))

    def _on_step(self) -> bool:
        due = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if due:
            self._steps = self._active = 0
        keep_going = super()._on_step()
        if due and self._steps:
            rate = self._active / self._steps
            self.intervention_timesteps.append(self.num_timesteps)
            self.intervention_rates.append(rate)
            self.logger.record("eval/intervention_rate", rate)
            if self.log_path is not None:
                np.savez(Path(self.log_path).parent / "interventions.npz",
                         timesteps=np.array(self.intervention_timesteps),
                         intervention_rate=np.array(self.intervention_rates))
        return keep_going


def progress_callback(desc: str):
    """An SB3 callback drawing a tqdm progress bar (SB3's ``ProgressBarCallback`` where ``rich`` is installed)."""
    from stable_baselines3.common.callbacks import BaseCallback

    try:
        import rich  # noqa: F401
    except ImportError:
        pass
    else:
        from stable_baselines3.common.callbacks import ProgressBarCallback

        return ProgressBarCallback()

    from tqdm.auto import tqdm

    class _Tqdm(BaseCallback):
        def _on_training_start(self) -> None:
            total = self.locals["total_timesteps"] - self.model.num_timesteps
            self.bar = tqdm(total=total, desc=desc, unit="step", unit_scale=True, dynamic_ncols=True)
            self._last = 0

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            if self.n_calls - self._last >= 200:
                self._last = self.n_calls
                buf = self.model.ep_info_buffer
                if buf:
                    ret = float(np.mean([e["r"] for e in buf]))
                    landed = float(np.mean([bool(e.get("landed", False)) for e in buf]))
                    self.bar.set_postfix(ret=f"{ret:.1f}", landed=f"{landed:.0%}", refresh=False)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return _Tqdm()


__all__ = ["FilterEvalCallback", "progress_callback"]
