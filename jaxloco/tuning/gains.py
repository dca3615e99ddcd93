"""Tunable WBLC gains: a pytree of unconstrained parameters, kept positive by construction.

The WBLC takes its gains as data (``{task: PDGains}``, see
:func:`jaxloco.control.tasks.default_gains`), so they can be traced and differentiated.
A :class:`GainSpace` says which of them are tuned and how:

- each tuned gain is ``base * exp(s)`` with ``s`` unconstrained, ``s = 0`` at the hand-set
  value: positive by construction, and a step in ``s`` is a relative change, so gains that
  differ by orders of magnitude (CoM ``kp`` 220 vs body ``kd`` 20) share one learning rate;
- ``per_row=False`` (default) gives one scale per task and gain (the rows keep their
  ratios, e.g. the CoM's horizontal/vertical), ``True`` one per row;
- ``"task.bandwidth"`` tunes a task's kp and kd together, ``kp0 * exp(2 s)`` and
  ``kd0 * exp(s)``: for the task's error dynamics ``e'' + kd e' + kp e = 0`` this scales the
  natural frequency ``sqrt(kp)`` by ``exp(s)`` and keeps the damping ratio
  ``kd / (2 sqrt(kp))`` hand-set. One number per task instead of two, and the one that
  matters most, and the damping ratio cannot be traded away (tuned freely, kd fell until
  the task was under-damped: docs/architecture.md, measured choices).

Gains not named stay as they are and get no gradient.

Gait numbers that are data per robot can be tuned too: ``"gait.replan_gamma"`` (Eq. 34's
blend, in [0, 1]) is ``sigmoid(logit(hand-set) + s)``, so it stays inside (0, 1), and
``"gait.replan_threshold"`` (Eq. 33's trigger, > 0) is ``hand-set * exp(s)``; ``s = 0`` is
again the hand-set value (:meth:`GainSpace.gait_values`). The threshold's pathwise
derivative is zero almost everywhere (it only decides *when* a replan fires), so tune it
with ``TuneConfig(gradient="smoothed")``. Results are saved with
:func:`jaxloco.control.gains.save_gains`, a small JSON file every experiment loads with
``gains_file=...`` on its command line.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxloco.control.gains import GAIN_KINDS

GAIT = "gait"
TUNABLE_GAIT = ("replan_gamma", "replan_threshold")
"""Gait numbers a :class:`GainSpace` can tune (``"gait.<name>"``)."""
BANDWIDTH = "bandwidth"
"""``"task.bandwidth"``: the task's kp and kd scaled together at a fixed damping ratio."""
TASK_KINDS = (*GAIN_KINDS, BANDWIDTH)


@dataclasses.dataclass(frozen=True)
class GainSpace:
    """Which gains are tuned: ``"task.kp"`` / ``"task.kd"`` / ``"task.bandwidth"`` names,
    e.g. ``"body_ori.kp"``, and ``"gait.replan_gamma"`` / ``"gait.replan_threshold"``."""

    tuned: tuple[str, ...] = ("body_ori.kp", "body_ori.kd")
    """The tuned gains' names."""
    per_row: bool = False
    """One scale per task row instead of per task and gain (the gait's numbers stay scalar)."""
    max_log_scale: float = 3.0
    """Scales are clipped to ``exp(+-max_log_scale)`` of the hand-set gains (x20 at 3)."""

    def __post_init__(self):
        if not self.tuned:
            raise ValueError("GainSpace.tuned: name at least one gain, e.g. 'body_ori.kp'")
        for name in self.tuned:
            task, _, kind = name.partition(".")
            if task == GAIT:
                if kind not in TUNABLE_GAIT:
                    raise ValueError(
                        f"GainSpace.tuned: {name!r}: the tunable gait numbers are "
                        f"{[f'{GAIT}.{k}' for k in TUNABLE_GAIT]}"
                    )
            elif not task or kind not in TASK_KINDS:
                raise ValueError(
                    f"GainSpace.tuned: {name!r} must be 'task.kp', 'task.kd' or "
                    f"'task.{BANDWIDTH}' (task: a name in the WBLC config) or one of "
                    f"{[f'{GAIT}.{k}' for k in TUNABLE_GAIT]}"
                )
        if len(set(self.tuned)) != len(self.tuned):
            raise ValueError(f"GainSpace.tuned: names repeat in {self.tuned}")
        for name in self.tuned:
            task, kind = self.split(name)
            both = [f"{task}.{k}" for k in GAIN_KINDS if f"{task}.{k}" in self.tuned]
            if kind == BANDWIDTH and both:
                raise ValueError(
                    f"GainSpace.tuned: {name!r} already scales {task}'s kp and kd; do not also "
                    f"tune {both}"
                )
        if not self.max_log_scale > 0:
            raise ValueError(f"GainSpace.max_log_scale must be > 0; got {self.max_log_scale}")

    def split(self, name: str) -> tuple[str, str]:
        task, _, kind = name.partition(".")
        return task, kind

    @property
    def task_gains(self) -> tuple[str, ...]:
        """The tuned WBLC gains (names without the gait numbers)."""
        return tuple(n for n in self.tuned if self.split(n)[0] != GAIT)

    @property
    def gait_numbers(self) -> tuple[str, ...]:
        """The tuned gait numbers (``"replan_gamma"``, ...)."""
        return tuple(self.split(n)[1] for n in self.tuned if self.split(n)[0] == GAIT)

    def check(self, base_gains: dict) -> None:
        """Raise if a tuned gain names a task the controller does not have."""
        for name in self.task_gains:
            task, _ = self.split(name)
            if task not in base_gains:
                raise ValueError(
                    f"GainSpace.tuned: no task {task!r} in the controller; tasks are "
                    f"{sorted(base_gains)}"
                )

    def init(self, base_gains: dict, dtype=None) -> dict:
        """The parameters at the hand-set gains: all log-scales zero (dtype: JAX's default)."""
        self.check(base_gains)
        out = {}
        for name in self.tuned:
            task, kind = self.split(name)
            per_row = self.per_row and task != GAIT
            rows = (
                getattr(base_gains[task], "kp" if kind == BANDWIDTH else kind) if per_row else None
            )
            size = np.shape(rows)[0] if per_row else 1
            out[name] = jnp.zeros(size, dtype)
        return out

    def gains(self, params: dict, base_gains: dict) -> dict:
        """The WBLC gains pytree for ``params`` (differentiable)."""
        self.check(base_gains)
        gains = dict(base_gains)
        for name in self.task_gains:
            task, kind = self.split(name)
            s = jnp.clip(params[name], -self.max_log_scale, self.max_log_scale)
            # bandwidth: kp ~ omega^2 and kd ~ omega at a fixed damping ratio.
            powers = {"kp": 2.0, "kd": 1.0} if kind == BANDWIDTH else {kind: 1.0}
            scaled = {}
            for k, power in powers.items():
                base = jnp.asarray(getattr(gains[task], k))
                scaled[k] = base * jnp.exp(power * s).astype(base.dtype)
            gains[task] = gains[task].replace(**scaled)
        return gains

    def gait_values(self, params: dict, base_gait: dict) -> dict:
        """``{name: value}`` of the tuned gait numbers (differentiable); ``base_gait``
        holds their hand-set values (e.g. ``dataclasses.asdict(GaitParams())``)."""
        out = {}
        for kind in self.gait_numbers:
            s = jnp.clip(params[f"{GAIT}.{kind}"], -self.max_log_scale, self.max_log_scale)
            if kind == "replan_gamma":
                # Kept off 0 and 1, where the logit is infinite.
                g0 = float(np.clip(base_gait[kind], 1e-3, 1 - 1e-3))
                out[kind] = jax.nn.sigmoid(np.log(g0 / (1 - g0)) + s[0])
            else:  # a positive number: a relative change, like the gains
                out[kind] = float(base_gait[kind]) * jnp.exp(s[0])
        return out


def tuned_values(space: GainSpace, params: dict, base_gains: dict) -> dict:
    """``{task: {"kp": [...], "kd": [...]}}`` of the tuned tasks as plain lists: the form
    a gains file holds (:func:`~jaxloco.control.gains.save_gains`)."""
    gains = space.gains(params, base_gains)
    tasks = sorted({space.split(n)[0] for n in space.task_gains})
    return {
        t: {k: np.asarray(getattr(gains[t], k), float).tolist() for k in GAIN_KINDS} for t in tasks
    }
