"""The peer on the same robot: Brax's PPO on the paper's Half-Cheetah, at the paper's sample budget;
and Brax's PPO on Gymnasium's v5 tasks (``env``: nmrl/adapters/brax_task.py). The run and the
command ``nmrl baseline``.

``run(BaselineConfig(seed=s), out)`` trains ``brax.training.agents.ppo.train`` on
:class:`nmrl.adapters.brax_env.BraxHalfCheetah` (the paper's robot, state, reward (8)-(14) and stop
rule; Brax's wrappers do the auto-reset, the stop is a truncation) for ``num_timesteps`` control
steps (default 2.5*10^7: the samples of 10^5 trials of ~250 steps, the paper's budget), in a run
directory of the run store's layout (nmrl/runs/store.py)::

    OUT/config.json     the BaselineConfig (resume may change only num_timesteps)
    OUT/metrics.jsonl   one row per PPO iteration (batch_size * num_minibatches * unroll_length
                        control steps): step, wall time, the learning's average reward and forward
                        speed per control step (the exploring policy, every step since the previous
                        row, the paper's measure: nmrl.adapters.brax_env.Tally), the trials ended, and
                        this policy evaluated deterministically for ``eval_seconds``
                        (nmrl.analysis.evaluate.rollout_policy)
    OUT/checkpoints/N   the normalizer, policy and value parameters after N control steps (orbax,
                        nmrl.runs.checkpoint.save_tree), every iteration, newest 3 kept
    OUT/compact.npz     the newest of them as one small file (checkpoint.save_tree_compact, ~1 MB):
                        what results/baseline_ppo/ commits while the run is unfinished, so that a
                        fresh clone continues it (a finished seed's is not committed: its
                        ``--resume`` needs no parameters and does nothing)
    OUT/resumes.jsonl   one line per resume

The config, Brax's setting and every change from it are nmrl/experiments/baseline_config.py's;
Brax's PPO, its networks, policy and evaluation nmrl/experiments/baseline_brax.py's. On a task
(``env``: halfcheetah-v5, hopper-v5, walker2d-v5) each row holds, per iteration, the deterministic
policy's returns of 10 episodes (``eval_return``: mean, nmrl.analysis.task_eval.act_episodes, the
reset states of ``nmrl eval``) in place of the 10 s rollout.

**Resume** (``resume=True``): Brax's ``ppo.train`` runs as one call that cannot be checkpointed
mid-way; it can start from given parameters (``restore_params``). An interrupted run therefore
continues from its newest checkpoint's parameters and normalizer (or, with no ``checkpoints/``, from
``compact.npz``: the same arrays, so the same continuation) with a fresh Adam state, fresh
environments (every trial starts anew) and a new PRNG stream (``seed`` folded with the resume
count): statistically, not bitwise, the uninterrupted run. An uninterrupted run is exactly Brax's
PPO. SIGINT/SIGTERM stop after the iteration in flight is saved (:class:`nmrl.runs.errors.Stopped`).
A failure ends ``nmrl baseline`` with one line and the exit status of every nmrl command
(nmrl/runs/command.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import sys
import threading
import time
from typing import Any

import jax
import numpy as np

from nmrl import options, tasks
from nmrl.adapters import brax_env
from nmrl.experiments import baseline_brax
from nmrl.experiments.baseline_config import BaselineConfig, check_resume, load_config, stored, task_config
from nmrl.options import MAX_EVAL_SECONDS
from nmrl.runs import checkpoint, command, errors, loop, parser, preflight, signals, store
from nmrl.runs.resume import existing_step

__all__ = ["run", "finished_step", "main"]

PROG = "nmrl baseline"


class _Recorder:
    """The host side of one ``ppo.train`` call: sums the learning's rewards (``tally``, the sink of
    brax_env.Tally) and, after every iteration (Brax's ``policy_params_fn``), evaluates, checkpoints
    and appends the metrics row; raises :class:`errors.Stopped` after the save when a signal came."""

    def __init__(self, cfg: BaselineConfig, out: pathlib.Path, step0: int, stop: Any, progress: bool):
        self.cfg, self.out, self.step0, self.stop, self.progress = cfg, out, step0, stop, progress
        self.rows: list[dict] = []
        self.t0 = self.t_last = time.perf_counter()
        self._lock = threading.Lock()
        self._sums = np.zeros(4)  # reward, forward speed, stops, steps since the last row

    def tally(self, reward, speed, stops, steps) -> None:
        """brax_env.Tally's sink (numpy only: it runs inside the training computation)."""
        with self._lock:
            self._sums += np.array([reward, speed, stops, steps], np.float64)

    def _take(self) -> np.ndarray:
        with self._lock:
            s, self._sums = self._sums, np.zeros(4)
        return s

    def on_params(self, current_step: int, _make_policy: Any, params: Any) -> None:
        if current_step == 0:
            if self.step0 == 0:  # the initial policy, evaluated once (fresh run)
                self._record(0, params, compile_s=time.perf_counter() - self.t0)
            self.t_last = time.perf_counter()
            return
        self._record(self.step0 + int(current_step), params)
        if self.stop.signal is not None:  # the signal guard's first signal: stop after this save
            raise errors.Stopped(self.stop.signal, self.step0 + int(current_step), self.rows)

    def _record(self, step: int, params: Any, compile_s: float | None = None) -> None:
        now = time.perf_counter()
        wall = now - self.t_last
        jax.effects_barrier()  # every report of this iteration's steps has reached tally()
        r, v, stops, n = self._take()
        ev = baseline_brax.evaluate_params(self.cfg, params)
        ev.pop("_traj", None)
        row = {"step": step, "iteration": step // self.cfg.steps_per_iteration, "wall_s": wall,
               "steps_per_s": (self.cfg.steps_per_iteration / wall) if step and wall > 0 else None,
               "train_reward_per_step": r / n if n else None, "train_forward_speed": v / n if n else None,
               "train_steps_tallied": int(n), "trials_ended": int(stops),
               **_eval_fields(ev), "eval_forward_speed": ev["forward_speed"],
               "eval_nonfinite": ev["nonfinite"], "unix_time": time.time()}
        if compile_s is not None:
            row["setup_s"] = compile_s
        meta = {"kind": "brax-ppo", "config": stored(self.cfg)}
        self.stop.at("saving")
        checkpoint.save_tree(self.out, step, params, meta)
        checkpoint.save_tree_compact(self.out, step, params, meta)
        store.append_metrics(self.out, row)
        self.stop.at("training")
        self.rows.append(row)
        self.t_last = time.perf_counter()
        if self.progress:
            tr = row["train_reward_per_step"]
            ev_text = (f"return {row['eval_return']:+.1f}" if "eval_return" in row else f"{row['eval_avg_reward']:+.3f}")
            print(f"ppo seed {self.cfg.seed}: {step:>11,} steps  train {tr if tr is None else f'{tr:+.3f}'}  "
                  f"eval {ev_text} ({row['eval_forward_speed']:+.2f} m/s)  "
                  f"{row['steps_per_s'] or 0:,.0f} steps/s", file=sys.stderr, flush=True)


def _eval_fields(ev: dict) -> dict:
    """A metrics row's evaluation: the paper robot's average reward per step, a task's episode returns."""
    if "return" not in ev:
        return {"eval_avg_reward": ev["avg_reward"]}
    return {"eval_return": ev["return"]["mean"], "eval_return_sd": ev["return"]["sd"],
            "eval_length_mean": float(np.mean(ev["length"])), "eval_terminated": ev["terminated"]}


def finished_step(out: str | os.PathLike, cfg: BaselineConfig) -> int | None:
    """The last metrics row's control step when it reaches ``cfg``'s budget (``iterations`` whole
    iterations: the run is finished), else None."""
    rows = store.read_metrics(pathlib.Path(out))
    if rows and rows[-1]["step"] // cfg.steps_per_iteration >= cfg.iterations:
        return int(rows[-1]["step"])
    return None


def run(cfg: BaselineConfig, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
        max_iterations: int | None = None, grace_s: float | None = None) -> list[dict]:
    """Train (or, with ``resume``, continue) the PPO baseline in ``out``; returns the rows written.

    ``max_iterations`` stops after that many iterations of this call (for tests and chunked
    sessions; the run continues with ``resume``). ``grace_s``: after a first SIGINT/SIGTERM, the
    seconds the iteration in flight has to finish and be saved before the process stops with its
    last saved iteration (nmrl/runs/signals.py; None: it waits for the iteration). Raises errors.RunError for a bad ``out`` or a
    resume with another config, errors.Stopped after SIGINT/SIGTERM (everything saved).
    """
    out = pathlib.Path(out)
    cfg.validate(len(jax.local_devices()))  # bad values are named first, with or without Brax
    brax_env.require_brax()
    template = None
    step0, n_resume = 0, 0
    if resume:
        saved = load_config(out)
        check_resume(cfg, saved, out)
        template = baseline_brax.initial_params(saved)
        if existing_step(out) is not None:
            meta, params = checkpoint.restore_tree(out, template)
        elif checkpoint.has_compact(out):  # a fresh clone of an unfinished published run: the same parameters
            meta, params = checkpoint.restore_tree_compact(out, template)
        elif finished_step(out, cfg) is not None:
            return []  # a fresh clone of a finished published seed (no parameters kept): nothing to do
        else:
            rows = store.read_metrics(out)
            reached = f"its metrics reach {rows[-1]['step']:,} control steps" if rows else "it has no metrics"
            raise errors.RunError(
                f"{out}: no checkpoint (or compact.npz) to resume from, and the run is not finished "
                f"({reached}, --num-timesteps is {cfg.num_timesteps:,}); a published seed keeps its "
                f"parameters (compact.npz) only while it is unfinished")
        step0 = int(meta["step"])
        if cfg.iterations - step0 // cfg.steps_per_iteration <= 0:
            return []  # finished: nothing to continue, nothing written
        store.truncate_metrics(out, step0)
        n_resume = len(store.read_jsonl(out / store.RESUMES_FILE)) + 1
        store.append_resume(out, {"from_step": step0, "num_timesteps": cfg.num_timesteps,
                                  "unix_time": time.time()})
        store.atomic_write_json(out / store.CONFIG_FILE, stored(cfg))
    else:
        preflight.fresh_out(out)
        preflight.create_dir(out)
        store.atomic_write_json(out / store.CONFIG_FILE, stored(cfg))
        params = None
    spi = cfg.steps_per_iteration
    left = cfg.iterations - step0 // spi
    if max_iterations is not None:
        left = min(left, max_iterations)
    if left <= 0:
        return []
    ppo_train, _, _ = baseline_brax.brax_ppo()
    seed = cfg.seed if n_resume == 0 else int(jax.random.randint(
        jax.random.fold_in(jax.random.PRNGKey(cfg.seed), n_resume), (), 0, 2**31 - 1))
    with loop.guarded() as guard:  # the command's signal guard, as every run of nmrl has
        guard.grace_s = grace_s
        guard.at("training")
        rec = _Recorder(cfg, out, step0, guard, progress)
        with guard.chunk():  # Brax's iterations: what a grace that ran out cuts (each saves in _record)
            ppo_train.train(baseline_brax.environment(cfg), num_timesteps=left * spi, num_evals=left + 1, seed=seed,
                            restore_params=params, policy_params_fn=rec.on_params,
                            **baseline_brax.train_kwargs(cfg, rec.tally))
    return rec.rows



# ----------------------------------------------------------------------------- command line


def main(argv: list[str] | None = None) -> int:
    """``nmrl baseline ppo ...`` (train or continue) and ``nmrl baseline eval RUN`` (evaluate)."""
    d = BaselineConfig()
    ap = parser.OneLineParser(prog=PROG, description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ppo", help="train Brax PPO on the paper's Half-Cheetah (needs pip install -e '.[brax]')")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its newest checkpoint")
    # every field of the config declared an option (nmrl/options.py), the environment's as EnvFields declares it
    parser.add_fields(p, BaselineConfig, helps={"env": f"{options.helps(tasks.EnvFields)['env']}; a task runs at its "
                                                       f"own control step with its time limit (default: {d.env})"})
    p.add_argument("--max-iterations", type=parser.integer, default=None,
                   help="stop after this many PPO iterations of this call (continue with --resume)")
    p.add_argument("--devices", default="auto", help="CPU devices Brax splits the environments over")
    p.add_argument("--quiet", action="store_true")
    parser.add_grace_option(p)
    e = sub.add_parser("eval", help="evaluate a PPO baseline checkpoint like nmrl eval (JSON, strobe, GIF)")
    e.add_argument("run")
    e.add_argument("--step", type=parser.integer, default=None)
    e.add_argument("--seconds", type=float, default=10.0)
    e.add_argument("--out", default=None, metavar="DIR", help="default: RUN/eval")
    e.add_argument("--no-render", action="store_true")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "eval":
            if not (math.isfinite(a.seconds) and 0 < a.seconds <= MAX_EVAL_SECONDS):
                raise ValueError(f"--seconds={a.seconds!r} is invalid: must be in (0, {MAX_EVAL_SECONDS:g}]")
            res = baseline_brax.evaluate_checkpoint(a.run, a.step, seconds=a.seconds, render=not a.no_render,
                                                    out_dir=a.out)
            print(json.dumps(res, indent=2))
            return 0
        if a.max_iterations is not None and a.max_iterations < 1:
            raise ValueError(f"--max-iterations={a.max_iterations} is invalid: must be >= 1")
        grace_s = signals.grace_of(a.grace_s)
        given = parser.given_fields(a, BaselineConfig)
        if a.env is not None and not a.resume:
            base = task_config(a.env)  # the task's own control step and time limit
        else:
            base = load_config(a.out) if a.resume else BaselineConfig()
        cfg = dataclasses.replace(base, **given)  # a resume refuses any change but num_timesteps (run)
        run(cfg, a.out, resume=a.resume, progress=not a.quiet, max_iterations=a.max_iterations, grace_s=grace_s)
    except errors.Stopped as err:
        print(f"{PROG}: {err}; saved; continue with --resume", file=sys.stderr)
        return err.exit_status
    except Exception as err:  # noqa: BLE001 - bad input (Brax missing too), the disk, another writer; else a bug
        status = command.exit_status(PROG, err, (ValueError, ImportError, errors.RunError, checkpoint.CheckpointError))
        if status is None:
            raise
        return status
    return 0
