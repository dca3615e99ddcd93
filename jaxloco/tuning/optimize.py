"""The tuning loop: optax over a loss of the gain parameters, with safety checks.

:func:`tune` minimises ``loss_fn(params) -> (loss, aux)`` with

- ``adam``: Adam after clipping the gradient's global norm (``clip_norm``);
- ``lbfgs``: optax's L-BFGS with a backtracking (Armijo) line search, which needs loss
  values only, not gradients, at its trial points; each trial is one more rollout, so an
  iteration costs several (worth it on smooth, small problems).

Gradients (``gradient``): ``forward`` (default) pushes one tangent per parameter through
the rollout with ``jax.jvp`` (vmapped; the primal is computed once). It costs about (1 + P)
rollouts for P parameters and needs memory independent of the horizon. ``reverse`` is
``jax.value_and_grad``: its cost does not grow with P, but it compiles about twice as long,
so it pays only for many parameters (``benchmarks/bench_tuning.py``).

Every iteration checks the loss and the gradient: a non-finite value, or a gradient norm
above ``max_grad_norm``, stops the loop with :class:`TuningDiverged` naming the iteration
and what went wrong (the parameters of the last good iteration are attached). The loop
keeps the best parameters seen and a history (loss, aux terms, gradient norm, wall time),
shows a progress bar, and calls ``callback(record)`` each iteration (e.g. to checkpoint);
:func:`tune_in_dir` uses it to keep the history on disk while the loop runs.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree
from tqdm.auto import tqdm

from jaxloco import validation as v
from jaxloco.runtime import write_json

GRADIENT_MODES = ("forward", "reverse", "smoothed")


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    method: str = "adam"
    """``adam`` or ``lbfgs``."""
    gradient: str = "forward"
    """``forward`` (jvp per parameter), ``reverse`` (backpropagation) or ``smoothed`` (the
    gradient of the loss averaged over Gaussian perturbations of the parameters, from loss
    values only: for triggers such as the replan threshold, whose pathwise derivative is
    zero almost everywhere; see :func:`value_and_grad`)."""
    smoothing_sigma: float = 0.1
    """``smoothed``: the perturbations' standard deviation (parameter units: log-scales)."""
    smoothing_pairs: int = 4
    """``smoothed``: antithetic pairs of perturbations per gradient (2x this many losses)."""
    iterations: int = 20
    """Optimizer iterations at most."""
    learning_rate: float = 0.1
    """Adam's step (in log-gain units: 0.1 is a ~10% change of a gain)."""
    clip_norm: float = 1.0
    """Adam: clip the gradient to this global norm before the update."""
    max_grad_norm: float = 1e6
    """A gradient larger than this stops the loop (exploding gradients)."""
    tolerance: float = 0.0
    """Stop when the loss improves by less than this over ``patience`` iterations (0: off)."""
    patience: int = 5
    """Iterations over which ``tolerance`` is judged."""
    max_line_search: int = 12
    """L-BFGS: most backtracking halvings per iteration."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.one_of(self, "method", ("adam", "lbfgs")),
                v.one_of(self, "gradient", GRADIENT_MODES),
                *v.positive(self, "smoothing_sigma"),
                v.integer(self, "smoothing_pairs", 1),
                v.integer(self, "iterations", 1),
                *v.positive(self, "learning_rate", "clip_norm", "max_grad_norm"),
                *v.non_negative(self, "tolerance"),
                v.integer(self, "patience", 1),
            ],
        )


class TuningDiverged(RuntimeError):
    """The loss or its gradient went non-finite or exploded; ``last_good`` holds the
    parameters of the last iteration that was fine."""

    def __init__(self, message: str, last_good, history: list):
        super().__init__(message)
        self.last_good = last_good
        self.history = history


@dataclasses.dataclass
class TuneResult:
    params: object
    """The parameters with the lowest loss seen."""
    best_loss: float
    """The lowest loss seen."""
    history: list
    """One dict per iteration: loss, aux terms, grad_norm, wall_s."""
    stopped: str
    """Why the loop ended: ``iterations`` or ``converged``."""
    wall_s: float = float("nan")
    """Wall time of the whole loop, compiles included."""

    def summary(self) -> dict:
        """The numbers a run's ``summary.json`` reports about the tuning loop."""
        return {
            "tuning_wall_s": self.wall_s,
            "iterations": len(self.history),
            "stopped": self.stopped,
            "initial_loss": self.history[0]["loss"],
            "best_loss": self.best_loss,
        }

    def describe(self) -> str:
        s = self.summary()
        return (
            f"loss {s['initial_loss']:.5g} -> {s['best_loss']:.5g} in {s['iterations']} "
            f"iterations ({s['tuning_wall_s']:.0f} s)"
        )


def recorded_params(record: dict) -> dict:
    """The parameters of one history record (``{name: list}`` on disk) as arrays."""
    return {name: jnp.asarray(v) for name, v in record["params"].items()}


def value_and_grad(
    loss_fn: Callable, mode: str = "forward", sigma: float = 0.1, pairs: int = 4, seed: int = 0
) -> Callable:
    """``params -> ((loss, aux), grads)`` for ``loss_fn(params) -> (loss, aux)`` by forward
    (one ``jvp`` per parameter entry, vmapped) or reverse mode, or ``smoothed``.

    ``smoothed`` estimates the gradient of ``E[loss(params + sigma * eps)]``, ``eps`` standard
    normal, from ``2 * pairs`` loss values (vmapped): ``sum_i (loss(p + sigma eps_i) -
    loss(p - sigma eps_i)) eps_i / (2 sigma pairs)``. It needs no derivative of the loss, so
    it sees what a pathwise derivative cannot: a parameter that moves *when* a discrete
    event happens (the replan threshold) has zero pathwise derivative almost everywhere,
    while the smoothed loss has a slope. The perturbations are drawn once (``seed``), so the
    estimate is a deterministic function of ``params``; the loss and aux returned are those
    at ``params`` itself.
    """
    if mode == "reverse":
        return jax.value_and_grad(loss_fn, has_aux=True)
    if mode == "smoothed":
        return _smoothed_value_and_grad(loss_fn, sigma, pairs, seed)
    if mode != "forward":
        raise ValueError(f"gradient mode must be one of {GRADIENT_MODES}; got {mode!r}")

    def forward(params):
        flat, unravel = ravel_pytree(params)

        def along(tangent):
            (loss, aux), (dloss, _) = jax.jvp(lambda x: loss_fn(unravel(x)), (flat,), (tangent,))
            return loss, aux, dloss

        basis = jnp.eye(flat.size, dtype=flat.dtype)
        # The primal does not depend on the tangent, so vmap computes it once.
        loss, aux, dflat = jax.vmap(along, out_axes=(None, None, 0))(basis)
        return (loss, aux), unravel(dflat)

    return forward


def _smoothed_value_and_grad(loss_fn: Callable, sigma: float, pairs: int, seed: int):
    if not sigma > 0 or pairs < 1:
        raise ValueError(f"smoothed gradients need sigma > 0 and pairs >= 1; got {sigma}, {pairs}")

    def fn(params):
        flat, unravel = ravel_pytree(params)
        eps = jax.random.normal(jax.random.key(seed), (pairs, flat.size), flat.dtype)
        points = jnp.concatenate([flat[None], flat + sigma * eps, flat - sigma * eps])
        losses, auxes = jax.vmap(lambda x: loss_fn(unravel(x)))(points)
        diff = losses[1 : 1 + pairs] - losses[1 + pairs :]
        grad = jnp.tensordot(diff, eps, axes=1) / (2 * sigma * pairs)
        return (losses[0], jax.tree.map(lambda v: v[0], auxes)), unravel(grad)

    return fn


def robust_value_and_grad(
    sample_loss: Callable,
    samples,
    mode: str = "forward",
    max_sample_grad_norm: float = 100.0,
    **smoothing,
) -> Callable:
    """``params -> ((loss, aux), grads)`` for the mean over ``samples`` (leading axis) of
    ``sample_loss(params, sample) -> (loss, aux)``, where the gradient averages only the
    samples whose own gradient is finite and of norm <= ``max_sample_grad_norm``.

    Why: through a contact event (a touch-down, a new plan) a pathwise derivative can be
    orders of magnitude off what central differences give while the other samples' agree
    with theirs (``docs/tuning.md``). One such sample decides the
    mean; dropping it leaves the gradient of the samples that can be trusted. The loss
    still averages them all; ``aux["untrusted"]`` is the fraction dropped. ``smoothing``:
    ``sigma``, ``pairs``, ``seed`` of ``mode="smoothed"`` (:func:`value_and_grad`).
    """
    if not max_sample_grad_norm > 0:
        raise ValueError(f"max_sample_grad_norm must be > 0; got {max_sample_grad_norm}")

    def one(params, sample):
        return value_and_grad(lambda p: sample_loss(p, sample), mode, **smoothing)(params)

    def fn(params):
        (loss, aux), grads = jax.vmap(one, in_axes=(None, 0))(params, samples)
        norms = jax.vmap(optax.tree.norm)(grads)
        trusted = jnp.isfinite(norms) & (norms <= max_sample_grad_norm)
        weight = trusted / jnp.maximum(jnp.sum(trusted), 1)

        def mean_trusted(g):
            g = jnp.where(trusted.reshape((-1,) + (1,) * (g.ndim - 1)), g, 0.0)
            return jnp.tensordot(weight.astype(g.dtype), g, axes=1)

        aux = jax.tree.map(lambda v: jnp.mean(v, axis=0), aux)
        aux["untrusted"] = 1.0 - jnp.mean(trusted.astype(loss.dtype))
        return (jnp.mean(loss), aux), jax.tree.map(mean_trusted, grads)

    return fn


def optimizer(cfg: TuneConfig) -> optax.GradientTransformation:
    if cfg.method == "adam":
        return optax.chain(optax.clip_by_global_norm(cfg.clip_norm), optax.adam(cfg.learning_rate))
    return optax.lbfgs(
        linesearch=optax.scale_by_backtracking_linesearch(
            max_backtracking_steps=cfg.max_line_search
        )
    )


def tune(
    loss_fn: Callable,
    params,
    cfg: TuneConfig = TuneConfig(),
    progress: bool | str = True,
    callback: Callable[[dict], None] | None = None,
    loss_and_grad: Callable | None = None,
) -> TuneResult:
    """Minimise ``loss_fn(params) -> (loss, aux)`` from ``params`` (see the module doc).

    ``loss_and_grad``: an already jitted ``value_and_grad(loss_fn, cfg.gradient)`` to reuse
    (its compile is most of a short run's time)."""
    opt = optimizer(cfg)
    if loss_and_grad is None:
        loss_and_grad = jax.jit(
            value_and_grad(loss_fn, cfg.gradient, cfg.smoothing_sigma, cfg.smoothing_pairs)
        )
    plain_loss = jax.jit(lambda p: loss_fn(p)[0])

    @jax.jit
    def update(params, state, loss, grads):
        if cfg.method == "lbfgs":
            updates, state = opt.update(
                grads, state, params, value=loss, grad=grads, value_fn=plain_loss
            )
        else:
            updates, state = opt.update(grads, state, params)
        return optax.apply_updates(params, updates), state

    state = opt.init(params)
    history, best, best_loss, stopped = [], params, np.inf, "iterations"
    start = time.perf_counter()
    bar = tqdm(
        range(cfg.iterations),
        desc=progress if isinstance(progress, str) else "tuning",
        disable=not progress,
    )
    for it in bar:
        (loss, aux), grads = loss_and_grad(params)
        loss = float(loss)
        grad_norm = float(optax.tree.norm(grads))
        record = {
            "iteration": it,
            "loss": loss,
            "grad_norm": grad_norm,
            "wall_s": time.perf_counter() - start,
            **{k: float(v) for k, v in aux.items() if np.ndim(v) == 0},
            "params": jax.tree.map(lambda v: np.asarray(v).tolist(), params),
        }
        if not np.isfinite(loss):
            raise TuningDiverged(
                f"tuning: the loss is {loss} at iteration {it}; parameters there: "
                f"{record['params']}",
                best,
                history,
            )
        if not np.isfinite(grad_norm) or grad_norm > cfg.max_grad_norm:
            raise TuningDiverged(
                f"tuning: gradient norm {grad_norm:.3g} at iteration {it} (limit "
                f"max_grad_norm={cfg.max_grad_norm:g}); the loss is not smooth here: shorten "
                "the horizon, average over more pushes or lower the learning rate",
                best,
                history,
            )
        history.append(record)
        if callback is not None:
            callback(record)
        if loss < best_loss:
            best, best_loss = params, loss
        bar.set_postfix(loss=f"{loss:.4g}", best=f"{best_loss:.4g}", grad=f"{grad_norm:.2g}")
        if cfg.tolerance > 0 and it >= cfg.patience:
            if history[it - cfg.patience]["loss"] - best_loss < cfg.tolerance:
                stopped = "converged"
                break
        params, state = update(params, state, jnp.asarray(loss), grads)
    bar.close()
    return TuneResult(best, float(best_loss), history, stopped, time.perf_counter() - start)


def tune_in_dir(
    loss_fn: Callable,
    params,
    cfg: TuneConfig,
    run_dir: str | os.PathLike,
    progress: bool | str = "tuning",
    loss_and_grad: Callable | None = None,
) -> TuneResult:
    """:func:`tune`, keeping the history in ``run_dir``: ``history.json.partial`` grows
    one record per iteration while the loop runs (an interrupted run keeps its curve) and
    becomes ``history.json`` at the end."""
    run_dir = Path(run_dir)
    partial = run_dir / "history.json.partial"
    records = []

    def keep(record):
        records.append(record)
        write_json(partial, records)

    result = tune(loss_fn, params, cfg, progress, callback=keep, loss_and_grad=loss_and_grad)
    write_json(run_dir / "history.json", result.history)
    partial.unlink(missing_ok=True)
    return result
