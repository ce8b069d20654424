"""Training callbacks: periodic evaluation of the deployed policy (with the safety filter) that also records how
often the filter had to act, so the learning curves show the filter's share of the work; and the progress bar."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stable_baselines3.common.callbacks import EvalCallback


class FilterEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` (mean return, ``best_model.zip``) that also records how much the safety filter had
    to do for the policy: the share of evaluation steps in which it replaced the policy's action
    (``info["filter_active"]``), in ``eval/interventions.npz`` (``timesteps``, ``intervention_rate``,
    ``landing_rate``) and logged as ``eval/intervention_rate``.

    The evaluation environment decides ``best_model.zip`` by its mean return, in which a hard violation costs 100
    and a landing earns 100. With ``deployed_env`` (the same environment under a filter, for a policy that learns
    without one) each evaluation is repeated there and only recorded: choosing checkpoints by the filtered return
    would prefer one the filter flies (``docs/agents.md``). Without it, the evaluation environment's own
    interventions are recorded when it is filtered.

    :param deployed_env: a filtered evaluation environment, or ``None``
    """

    def __init__(self, *args, deployed_env=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.deployed_env = deployed_env
        self._steps = self._active = self._episodes = self._landed = 0
        self.records: dict[str, list[float]] = {"timesteps": [], "intervention_rate": [], "landing_rate": []}

    def _count(self, locals_, globals_) -> None:
        info = locals_["info"]
        self._steps += 1
        self._active += int(bool(info.get("filter_active", False)))
        if locals_.get("done"):
            self._episodes += 1
            self._landed += int(bool(info.get("landed", info.get("is_success", False))))

    def _log_success_callback(self, locals_, globals_) -> None:
        super()._log_success_callback(locals_, globals_)
        if self.deployed_env is None:
            self._count(locals_, globals_)

    def _on_step(self) -> bool:
        due = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if due:
            self._steps = self._active = self._episodes = self._landed = 0
        keep_going = super()._on_step()
        if due and self.deployed_env is not None:
            from stable_baselines3.common.evaluation import evaluate_policy

            evaluate_policy(self.model, self.deployed_env, n_eval_episodes=self.n_eval_episodes,
                            deterministic=self.deterministic, callback=self._count, warn=False)
        if due and self._steps:
            rate = self._active / self._steps
            for key, value in (("timesteps", self.num_timesteps), ("intervention_rate", rate),
                               ("landing_rate", self._landed / max(self._episodes, 1))):
                self.records[key].append(value)
            self.logger.record("eval/intervention_rate", rate)
            if self.log_path is not None:
                np.savez(Path(self.log_path).parent / "interventions.npz",
                         **{k: np.array(v) for k, v in self.records.items()})
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
