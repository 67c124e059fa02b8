"""Evaluate a saved policy: one trial of T seconds per policy, a JSON summary and pictures.

``evaluate(run_dir)`` restores only the config and the policy parameters of a checkpoint
(:func:`nmrl.runs.checkpoint.restore_params`; the actor-critic's theta, v), builds the Half-Cheetah
with the run's control step (no random stopping, no automatic reset: a rollout is one trial of
``seconds``), and runs one jitted ``lax.scan`` rollout of the run's learner's policy
(nmrl/learners/contract.py, ``Policy``) for

* ``deterministic``: a_t = act(params, s_t, 0) (the actor-critic: a~(s_t; theta));
* ``exploring``:     a_t = act(params, s_t, xi_t), xi the learner's exploration noise (the actor-critic:
  a~(s_t; theta) + xi_t, xi the run's nm-period AR noise (4) with its l, alpha, sigma).

Both use the same compiled program (the noise is scaled by a traced 0 or 1). The result is a
JSON-able dict (see :func:`evaluate`) written to ``RUN_DIR/eval/eval.json``; with ``render`` the
deterministic rollout is drawn as a Fig.-4-like strobe (``strobe.png``) and an animation
(``gait.gif``, real time, camera following the trunk; :mod:`nmrl.analysis.gait_pictures`), and its
joint positions are kept in ``trajectory.npz`` to redraw.
Same checkpoint and seed give the identical JSON. The outputs of one eval are one set: they are
written into a staging directory and put in place together, ``eval.json`` last, after the last
eval's ``eval.json`` and the outputs the new set lacks are removed; what a stopped eval left
(staging, temporary files) is removed by the next one.

The checkpoint must be of the run (its identity, ``RUN_DIR/config.json``: nmrl/runs/checkpoint.py);
without ``step`` a corrupted newest checkpoint is skipped with a warning naming it, and the newest
good one is evaluated. Nothing in the run directory but ``eval/`` is written.
"""

from __future__ import annotations

import functools
import json
import math
import os
import pathlib
import shutil
import sys
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners, tasks
from nmrl.analysis import eval_env, task_eval
from nmrl.analysis.gait_pictures import plot_strobe, strobe_every, write_gif
from nmrl.paper.env import REWARD_TERMS, EnvConfig
from nmrl.paper.robot import forward_kinematics
from nmrl.runs import checkpoint, io_errors
from nmrl.runs.store import atomic_path, atomic_write_text, fsync_path

__all__ = ["evaluate", "rollout", "rollout_params", "rollout_policy", "summarize", "plot_strobe", "write_gif", "GROUND_KEYS"]

#: ground_share key -> metric of nmrl.paper.env.
GROUND_KEYS = {"heel": "heel_ground", "knee": "knee_ground", "head": "head_ground"}
#: gait key -> joint (nmrl/paper/geometry.py: 0 the hind paw, 9 the front paw, 8 the wrist)
PAWS = {"hind_paw": 0, "front_paw": 9}
WRIST = 8
#: strides are counted from this time on (the trial starts at rest, hind paw 0.1 m up: Sec. V-C)
GAIT_FROM_S = 1.0
EVAL_DIR = "eval"
TRAJECTORY = "trajectory.npz"  #: the deterministic rollout's joint positions, written with the pictures
EVAL_JSON, STROBE, GIF = "eval.json", "strobe.png", "gait.gif"
#: the files of one eval's set (eval.json names the others when they were drawn)
OUTPUTS = (EVAL_JSON, STROBE, GIF, TRAJECTORY)
#: an eval's outputs are written into ``OUT_DIR/.staging.<pid>`` first, then put in place as one set
STAGING = ".staging."


# ----------------------------------------------------------------------------- rollout


def _physics(config: Any) -> str:
    """The physics a run trained on (configs that predate the field: MJX)."""
    return config.environment.physics


@functools.lru_cache(maxsize=8)
def _rollout_fn(program: Any, n_steps: int):
    """A jitted (params, key, noise_scale, noise_args) -> (traj, pos0, x0) for one trial of the
    learner's policy (nmrl/learners/contract.py, ``Policy``): ``a_t = act(params, s_t, noise_scale *
    xi_t)``, xi the learner's exploration noise. ``program``: the config with its traced fields at
    their defaults (:func:`nmrl.learners.program_key`), so every point of a sweep shares it."""
    env = eval_env.of_config(program)
    pol = learners.of(program).policy(program, env)

    def run(params, key, noise_scale, noise_args):
        k_reset, k_eps = jax.random.split(key)
        s0 = env.reset(k_reset)
        eps = jax.random.normal(k_eps, (n_steps, env.act_dim), jnp.float32)

        def step(carry, e):
            s, ns = carry
            ns, xi = pol.noise_step(noise_args, ns, e)
            s = env.step(s, pol.act(params, s.obs, noise_scale * xi))
            pos, _ = forward_kinematics(s.data.qpos)
            out = {"reward": s.reward, "pos": pos}
            for k in (*REWARD_TERMS, "forward_speed", "x", "nonfinite", *GROUND_KEYS.values()):
                out[k] = s.metrics[k]
            return (s, ns), out

        _, traj = jax.lax.scan(step, (s0, pol.noise_init(env.act_dim)), eps)
        pos0, _ = forward_kinematics(s0.data.qpos)
        return traj, pos0, s0.metrics["x"]

    return jax.jit(run)


def rollout_params(config, params: dict, *, seconds: float, seed: int, exploring: bool) -> dict[str, np.ndarray]:
    """One trial of ``seconds`` of a run's policy: ``params`` {field: tree} over its learner's
    ``policy_fields`` (what :func:`nmrl.runs.checkpoint.restore_params` gives), the deterministic
    policy or (``exploring``) the exploring one; numpy arrays per step (``pos``: (T+1, 10, 2))."""
    n_steps = _num_steps(seconds, config.environment.control_dt)
    fn = _rollout_fn(learners.program_key(config), n_steps)
    noise_args = learners.of(config).policy(config, eval_env.of_config(config)).noise_args
    traj, pos0, x0 = fn(params, jax.random.PRNGKey(seed), jnp.float32(1.0 if exploring else 0.0), noise_args)
    return _host_traj(traj, pos0, x0, config.environment.control_dt)


def rollout(config, theta, *, seconds: float, seed: int, exploring: bool) -> dict[str, np.ndarray]:
    """One trial of ``seconds`` of the actor-critic's policy a = a~(s; theta) (+ xi, the run's
    nm-period AR noise (4), when ``exploring``): :func:`rollout_params` with ``{"theta": theta}``."""
    return rollout_params(config, {"theta": theta}, seconds=seconds, seed=seed, exploring=exploring)


@functools.lru_cache(maxsize=8)
def _policy_rollout_fn(act: Callable, control_dt: float, n_steps: int, physics: str = "mjx"):
    """A jitted (params, key) -> (traj, pos0, x0) for one trial of ``a_t = act(params, s_t)``."""
    env = eval_env.eval_env(tasks.PAPER, control_dt, physics)

    def run(params, key):
        s0 = env.reset(key)

        def step(s, _):
            s = env.step(s, act(params, s.obs))
            pos, _ = forward_kinematics(s.data.qpos)
            out = {"reward": s.reward, "pos": pos}
            for k in (*REWARD_TERMS, "forward_speed", "x", "nonfinite", *GROUND_KEYS.values()):
                out[k] = s.metrics[k]
            return s, out

        _, traj = jax.lax.scan(step, s0, None, length=n_steps)
        pos0, _ = forward_kinematics(s0.data.qpos)
        return traj, pos0, s0.metrics["x"]

    return jax.jit(run)


def rollout_policy(act: Callable, params: Any, *, control_dt: float, seconds: float, seed: int = 0,
                   physics: str = "mjx") -> dict[str, np.ndarray]:
    """One trial of ``seconds`` of any deterministic policy ``act(params, obs) -> a`` (the paper's
    action, (6,); ``act`` a module-level function, it keys the compile cache), on the env of
    :func:`rollout`: no random stop, no reset. Same arrays as :func:`rollout` (see
    :func:`summarize`). Used for policies that are not the actor of nmrl.paper.networks (the PPO
    baseline, nmrl/experiments/baseline_ppo.py)."""
    n_steps = _num_steps(seconds, control_dt)
    traj, pos0, x0 = _policy_rollout_fn(act, float(control_dt), n_steps, physics)(params, jax.random.PRNGKey(seed))
    return _host_traj(traj, pos0, x0, control_dt)


def _host_traj(traj, pos0, x0, control_dt: float) -> dict[str, np.ndarray]:
    """A rollout's arrays on the host, ``pos`` with the initial pose prepended (T+1 rows)."""
    out = {k: np.asarray(v) for k, v in jax.device_get(traj).items()}
    out["pos"] = np.concatenate([np.asarray(pos0)[None], out["pos"]], axis=0)
    out["x0"] = np.asarray(x0)
    out["control_dt"] = float(control_dt)
    return out


def _num_steps(seconds: float, control_dt: float) -> int:
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a finite number > 0, got {seconds!r}")
    return max(1, int(round(seconds / control_dt)))


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def gait(pos: np.ndarray, x: np.ndarray, control_dt: float, contact_tol: float | None = None) -> dict[str, Any]:
    """Strides of one rollout, to compare gaits with the paper's words (Sec. V-D: for l = 1 "the
    object takes very fine strides or runs on its wrist and heel").

    ``pos`` (T+1, 10, 2): the joints' (x, y) at t = 0, dt, ..., T dt; ``x`` (T+1,): the trunk's x
    at the same times. From ``GAIT_FROM_S`` on (past the start from rest; from half the rollout when
    it is shorter than twice that), per paw (hind, front): ``touchdowns`` (steps where its height
    goes from above the contact tolerance, nmrl.paper.env's ``[y = 0]``, to at or below it),
    ``stride_frequency_hz`` (touchdowns per second), ``stride_length_m`` (the trunk's distance per
    touchdown; None without one), ``interval_cv`` (the coefficient of variation of the times between
    touchdowns: ~0 for a regular stride; None with fewer than 3 touchdowns), ``ground_share``
    (share of the steps it stands on the ground);
    and ``wrist_ground_share``. Also ``from_s``, the start of that window."""
    tol = EnvConfig().contact_tol if contact_tol is None else contact_tol
    n = len(x) - 1  # steps
    k0 = min(int(round(GAIT_FROM_S / control_dt)), n // 2)  # the window is t = k0 dt ... T dt
    y = np.asarray(pos)[k0:, :, 1]
    seconds = (n - k0) * control_dt
    dist = float(x[-1] - x[k0])
    out: dict[str, Any] = {"from_s": k0 * control_dt}
    for name, j in PAWS.items():
        down = y[:, j] <= tol
        at = np.flatnonzero(~down[:-1] & down[1:])  # touchdown steps
        touch, gaps = len(at), np.diff(at)
        out[name] = {"touchdowns": touch, "stride_frequency_hz": _num(touch / seconds),
                     "stride_length_m": _num(dist / touch) if touch else None,
                     "interval_cv": _num(np.std(gaps) / np.mean(gaps)) if len(gaps) >= 2 else None,
                     "ground_share": _num(np.mean(down[1:]))}
    out["wrist_ground_share"] = _num(np.mean(y[1:, WRIST] <= tol))
    return out


def summarize(traj: dict[str, np.ndarray]) -> dict[str, Any]:
    """The JSON summary of one rollout (:func:`rollout`, :func:`rollout_policy`)."""
    x = traj["x"]
    return {
        "avg_reward": _num(np.mean(traj["reward"], dtype=np.float64)),
        "forward_speed": _num(np.mean(traj["forward_speed"], dtype=np.float64)),
        "distance": _num(x[-1] - traj["x0"]),
        "terms": {k: _num(np.mean(traj[k], dtype=np.float64)) for k in REWARD_TERMS},
        "ground_share": {k: _num(np.mean(traj[m], dtype=np.float64)) for k, m in GROUND_KEYS.items()},
        "gait": gait(traj["pos"], np.concatenate([np.reshape(traj["x0"], (1,)), x]), traj["control_dt"]),
        "nonfinite": int(np.sum(traj["nonfinite"] > 0)),
    }


# ----------------------------------------------------------------------------- entry points


def evaluate(
    run_dir: str | os.PathLike,
    step: int | None = None,
    seconds: float = 10.0,
    seed: int = 0,
    *,
    render: bool = True,
    out_dir: str | os.PathLike | None = None,
    warn: Callable[[str], None] | None = None,
) -> dict:
    """Evaluate a checkpoint (newest good one if ``step`` is None); returns the JSON-able summary.

    Keys: ``run_dir, step, trials, seconds, steps, seed, control_dt``, the learner's own description
    (``Learner.describe``; the actor-critic: ``l, alpha, sigma``; other learners also ``learner``) and, under
    ``deterministic`` and ``exploring``: ``avg_reward`` (per control step), ``forward_speed`` (m/s,
    mean), ``distance`` (m the trunk moved), ``terms`` (each reward term (8)-(14), mean per step),
    ``ground_share`` {heel, knee, head} (share of steps with that joint on the ground),
    ``gait`` (stride frequency and length of each paw, wrist on the ground: :func:`gait`),
    ``nonfinite`` (steps whose physics failed). With ``render`` also ``files`` {strobe, gif,
    trajectory}: ``trajectory.npz`` holds the deterministic rollout's joint positions ``pos`` (T+1, 10,
    2) and ``control_dt``, so that gaits can be redrawn side by side at one scale.
    A run on a Gymnasium task (``--env``) is scored by :func:`nmrl.analysis.task_eval.episodes`
    instead: ``env``, ``episodes`` and, under ``deterministic`` and ``exploring``, the return per
    episode and the episodes' lengths; ``seconds`` does not apply and nothing is drawn.
    The JSON is also written to ``OUT_DIR/eval.json`` (``OUT_DIR`` = ``RUN_DIR/eval``).
    Raises CheckpointError for a missing/bad checkpoint or one of another run (ForeignCheckpoint),
    ValueError for bad ``seconds``, :class:`nmrl.runs.io_errors.IOFailure` (before the rollouts)
    when ``OUT_DIR`` cannot be written. A corrupted newest checkpoint skipped (``step`` None) is
    reported through ``warn`` (default: a line on stderr), one call per checkpoint naming its path.
    """
    run = pathlib.Path(run_dir)
    _num_steps(seconds, 1.0)  # a bad ``seconds`` fails before anything is read
    step, (meta, (config, *_)), skipped = select_policy(run, step)
    params = meta.pop("params")
    warn = warn or (lambda m: print(f"warning: {m}", file=sys.stderr, flush=True))
    for e in skipped:
        warn(f"{e}; evaluating the newest good checkpoint, step {step}, instead")
    n_steps = _num_steps(seconds, config.environment.control_dt)
    learner = learners.of(config)
    out_dir = pathlib.Path(out_dir) if out_dir is not None else run / EVAL_DIR
    io_errors.check_writable(out_dir)  # before the rollouts: IOFailure naming the directory and the cause
    env_name = config.environment.env
    if env_name != tasks.PAPER:  # a Gymnasium task: returns per episode, no pictures of the paper's robot
        render = False
        length = {"env": env_name, "episodes": task_eval.EPISODES}
        ends = {"deterministic": task_eval.episodes(config, params, seed=seed, exploring=False),
                "exploring": task_eval.episodes(config, params, seed=seed, exploring=True)}
    else:
        det = rollout_params(config, params, seconds=seconds, seed=seed, exploring=False)
        length = {"seconds": float(seconds), "steps": n_steps}
        ends = {"deterministic": summarize(det),
                "exploring": summarize(rollout_params(config, params, seconds=seconds, seed=seed, exploring=True))}
    result: dict[str, Any] = {
        "run_dir": str(run),
        "step": step,
        "trials": meta.get("trials"),
        **length,
        "seed": int(seed),
        "control_dt": float(config.environment.control_dt),
        "physics": _physics(config),
        **({} if config.environment.physics_timestep is None
           else {"physics_timestep": float(config.environment.physics_timestep)}),
        **({} if learner.name == learners.DEFAULT else {learners.KEY: learner.name}),
        **(learner.describe(config) if learner.describe is not None else {}),
        **ends,
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_stale(out_dir)
    stage = out_dir / f"{STAGING}{os.getpid()}"
    stage.mkdir()
    try:
        if render:
            span = (len(det["pos"]) - 1) * config.environment.control_dt  # the whole rollout (--seconds)
            every = strobe_every(span)
            title = f"{run.name}, step {step}, deterministic policy"  # the strobe adds its spacing and span
            dt = config.environment.control_dt
            plot_strobe(det["pos"], dt, stage / STROBE, every_s=every, span_s=span, title=title)
            write_gif(det["pos"], dt, stage / GIF)
            with atomic_path(stage / TRAJECTORY) as tmp:
                np.savez(tmp, pos=np.asarray(det["pos"], np.float32), control_dt=np.float64(config.environment.control_dt))
            result["files"] = {"strobe": str(out_dir / STROBE), "gif": str(out_dir / GIF),
                               "trajectory": str(out_dir / TRAJECTORY)}
        atomic_write_text(stage / EVAL_JSON, json.dumps(result, indent=2, allow_nan=False) + "\n")
        _commit(stage, out_dir)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return result


def _commit(stage: pathlib.Path, out_dir: pathlib.Path) -> None:
    """Put the staged outputs of one eval in place of the last eval's, eval.json last: the old
    eval.json goes first, then every old output the new set lacks (e.g. the pictures, for an eval
    without them), then the new files are renamed in, so that eval.json always stands beside
    outputs of its own eval (a stop in between leaves the new files without eval.json)."""
    new = {p.name for p in stage.iterdir()}
    (out_dir / EVAL_JSON).unlink(missing_ok=True)
    for name in OUTPUTS:
        if name not in new:
            (out_dir / name).unlink(missing_ok=True)
    for name in sorted(new - {EVAL_JSON}) + [EVAL_JSON]:
        os.replace(stage / name, out_dir / name)
    fsync_path(out_dir)


def remove_stale(out_dir: pathlib.Path) -> list[pathlib.Path]:
    """Remove what an eval stopped while it wrote ``out_dir`` left: its staging directory and the
    temporary files of its outputs (atomic writes: ``.<name>.<pid>.tmp<suffix>``). Called by the
    one writer of ``out_dir`` (``nmrl eval`` holds its lock), so no other eval is writing them."""
    gone = []
    stems = {pathlib.Path(n).stem for n in OUTPUTS}
    for p in out_dir.iterdir():
        if p.name.startswith(STAGING) and p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
            gone.append(p)
        elif p.name.startswith(".") and ".tmp" in p.name and p.name[1:].split(".", 1)[0] in stems:
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def select_policy(run: pathlib.Path, step: int | None = None):
    """``(step, (meta, (config, *params)), skipped)`` of the checkpoint ``step`` of ``run``, or of its
    newest good one (skipping corrupted ones: ``skipped``); refuses a checkpoint of another run.
    ``params`` are the learner's ``policy_fields`` in order (the actor-critic: theta, v), also as the
    dict ``meta["params"]``.

    A run without checkpoints but with a compact state (a published policy: ``compact.npz``) is
    evaluated from that state (:func:`nmrl.runs.checkpoint.restore_compact_params`)."""
    run_cfg = checkpoint.load_run_config(run)
    source = str(run / checkpoint.RUN_CONFIG)
    if checkpoint.uses_compact(run):
        meta, config, params = checkpoint.restore_compact_params(run, step)
        checkpoint.check_identity(meta, run_cfg, source)
        meta["params"] = params
        return meta["step"], (meta, (config, *params.values())), []

    def load(s: int):
        meta = checkpoint.load_metadata(run, s)
        checkpoint.check_identity(meta, run_cfg, source)
        _, config, params = checkpoint.restore_params(run, s)
        meta["params"] = params
        return meta, (config, *params.values())

    return checkpoint.newest_good(run, load, step)
