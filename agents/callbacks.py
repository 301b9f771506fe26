"""The training run's callbacks, as stable-baselines3 writes its own: module-level classes, each one
concern, combined in a ``CallbackList`` by :func:`agents.training.train`.

    CallbackList([CriticBurnIn(20_000), EveryCrossing(25_000, 8, evaluate), Progress(report, n)])

:class:`Patience` is the rule that ends a run once its evaluations stop improving; the
evaluation feeds it and :class:`StopWhen` ends the training when it says so.

Importing this module imports stable-baselines3 (and torch): :mod:`agents.training` imports it
only when it trains.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["CriticBurnIn", "EveryCrossing", "LearningRateAt", "Patience", "Progress", "StopWhen"]


class CriticBurnIn(BaseCallback):
    """An off-policy actor (SAC, TD3) stays still for the first ``steps`` steps while its critic
    learns (residual policy learning's burn-in): no gradient reaches it until then."""

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.steps = int(steps)

    def _on_step(self) -> bool:
        actor = getattr(self.model.policy, "actor", None)
        if actor is not None:
            actor.requires_grad_(self.num_timesteps >= self.steps)
        return True


class EveryCrossing(BaseCallback):
    """``action(steps)`` each time the step count crosses a multiple of ``every`` (the vectorised
    env takes ``n_envs`` steps at a time, so the count steps over the multiples)."""

    def __init__(self, every: int, n_envs: int, action: Callable[[int], None]) -> None:
        super().__init__()
        self.every, self.n_envs, self.action = int(every), int(n_envs), action

    def _on_step(self) -> bool:
        n = self.num_timesteps
        if n // self.every != (n - self.n_envs) // self.every:
            self.action(n)
        return True


class Progress(BaseCallback):
    """``report(steps, total)`` after every step (a progress bar)."""

    def __init__(self, report: Callable[[int, int], None], total: int) -> None:
        super().__init__()
        self.report, self.total = report, int(total)

    def _on_step(self) -> bool:
        self.report(self.num_timesteps, self.total)
        return True


class LearningRateAt(BaseCallback):
    """PPO's update of a rollout that starts at the run's absolute step count ``s`` runs at the
    learning rate ``rate(s)``: a schedule of the whole run, where SB3's own is of
    ``progress_remaining``, relative to each ``learn`` call, which a resumed run restarts."""

    def __init__(self, rate: Callable[[int], float]) -> None:
        super().__init__()
        self.rate = rate

    def _set(self) -> None:
        from stable_baselines3.common.utils import FloatSchedule

        self.model.lr_schedule = FloatSchedule(self.rate(self.num_timesteps))

    def _on_rollout_start(self) -> None:
        self._set()

    def _on_step(self) -> bool:
        return True


class Patience:
    """The patience rule: a run stops once ``evaluations`` evaluations in a row have not improved
    on the bar by ``improvement`` (relative: 0.02 is 2 %). The bar is the first evaluation, then
    each one that beats it by that much: slow gains add up against it (1 % an evaluation resets
    it every third evaluation), noise around a plateau does not. ``update(error)`` takes an
    evaluation's error (lower is better; the trainer's: the geometric mean over the scenarios of
    the settled RMS, mm) and returns whether to stop. ``evaluations = 0`` never stops."""

    def __init__(self, evaluations: int, improvement: float = 0.02) -> None:
        self.evaluations, self.improvement = int(evaluations), float(improvement)
        self.bar = math.inf
        self.waited = 0
        self.stopped = False

    def update(self, error: float) -> bool:
        if error < self.bar * (1.0 - self.improvement) or (
            math.isinf(self.bar) and math.isfinite(error)
        ):
            self.bar, self.waited = float(error), 0
        else:
            self.waited += 1
        self.stopped = self.evaluations > 0 and self.waited >= self.evaluations
        return self.stopped


class StopWhen(BaseCallback):
    """Ends the training (SB3 stops when a callback returns False) once ``stop()`` is true."""

    def __init__(self, stop: Callable[[], bool]) -> None:
        super().__init__()
        self.stop = stop

    def _on_step(self) -> bool:
        return not self.stop()
