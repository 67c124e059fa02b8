"""The gradient's signal-to-noise ratio (eq. (1)) at matched policies: the same policies measured at
every control step (docs/exploration-study-2.md).

Eq. (1)'s argument is about one policy: as the control step shrinks, one action's perturbation
moves the return less, and the policy gradient estimated from a fixed amount of experience grows
noisier relative to its mean. Measured on different policies (each δ's own training), the ratio
would also compare what each δ has learned. Here the policies are fixed: white's 20 ms runs of
seeds 0..``seeds``-1 after 0, 4, 8 and 16 PPO iterations (iteration 0: the initial networks with
the observation statistics of the first iteration's batch, the ones PPO's first update uses; later
ones: the runs' compact states, their observation statistics as in training). Each policy is put at
every δ in :data:`DTS` (its networks, its value net and its normaliser unchanged; the reward scale
δ / 20 ms and the trial rate as in every cell) and its PPO gradient estimate (nmrl/experiments/
ppo_gradsnr.py: the surrogate's gradient at θ_old from one environment's 102.4 s of experience)
is measured with two explorations: white at the policy's own σ, and nm-periods learned on periods
as wholes (the period's density, eq. (7)) with NMp's screened settings at that δ. The SNR is per
second of one environment's experience; its interval is over the seeds.

Rows (``snr.csv``): seed, iteration, control step, arm, and ppo_gradsnr's statistics.
"""

from __future__ import annotations

import json
import pathlib
from typing import Any, Sequence

import jax

from nmrl import options
from nmrl.experiments import ppo_gradsnr
from nmrl.learners.ppo import PPOState, make_ppo
from nmrl.learners.ppo_config import PPOConfig
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import compact, store

DTS = (0.02, 0.005, 0.0025)
ITERATIONS = (0, 4, 8, 16)
BATCHES, WARMUP = 2, 1
COLUMNS = ("seed", "iteration", "control_dt", "arm", "seconds_per_estimate", "trcov", "trcov_ci", "mean_sq",
           "mean_sq_ci", "snr_per_s")
EXPLORATION_FIELDS = ("exploration", "sigma", "period_s", "corr_time_s", "beta", "f_min_hz", "f_max_hz", "order",
                      "period_wise")
POLICY_FIELDS = ("policy", "value", "obs_stats")


def config_at(cfg: PPOConfig, dt: float, exploration: dict) -> PPOConfig:
    """``cfg``'s learner at control step ``dt`` with ``exploration`` (the config fields of an arm):
    the reward scale dt / 20 ms as in every cell, the trial rate in seconds kept, no budget."""
    return options.replace(cfg, control_dt=dt, reward_scale=dt / DELTA_0, steps=None, trials=None,
                               chunk_steps=None, **exploration).resolved()


def exploration_of(config: dict) -> dict:
    """An arm's exploration fields from a point's config.json."""
    return {k: config[k] for k in EXPLORATION_FIELDS if k in config}


def matched_state(cfg: PPOConfig, point: pathlib.Path, *, initial: bool = False, env: Any = None) -> PPOState:
    """A state of ``cfg`` (any control step and exploration) holding the policy of the run in
    ``point`` (its compact state): its policy and value networks and observation statistics, or
    with ``initial`` the run's initial networks (the same key as its run: ``PRNGKey(seed)``) and the
    point's observation statistics. Environments and noise start fresh (``env``: as for make_ppo)."""
    meta, arrays = compact.load_compact(point)
    run = json.loads((point / "config.json").read_text())
    st = make_ppo(cfg, env).init(jax.random.PRNGKey(int(run["seed"])))
    parts = compact.fields_of(meta, arrays, st, ("obs_stats",) if initial else POLICY_FIELDS)
    return st.replace(**parts)


def measure(points: dict[int, dict[int, pathlib.Path]], arms: dict[str, dict[float, dict]], path: pathlib.Path,
            dts: Sequence[float] = DTS, batches: int = BATCHES, warmup: int = WARMUP, env: Any = None) -> list[dict]:
    """``snr.csv`` at ``path``: for every iteration of ``points`` ({iteration: {seed: point dir}};
    iteration 0 reads the first iteration's point for its statistics), control step and arm
    ({arm: {dt: exploration fields}}), the SNR of each seed's policy. Groups already in the file
    are kept (the measurement continues where it stopped); each group is appended whole (``env``:
    as for make_ppo, one built from the config when None)."""
    done = store.read_csv(path) if path.is_file() else []
    have = {(int(r["iteration"]), float(r["control_dt"]), r["arm"]) for r in done}
    for it, by_seed in sorted(points.items()):
        base = options.build(PPOConfig, **{k: v for k, v in json.loads((next(iter(by_seed.values())) / "config.json")
                                                                        .read_text()).items()
                                           if k in options.leaves(PPOConfig)})
        for dt in dts:
            for arm, by_dt in arms.items():
                if (it, dt, arm) in have:
                    continue
                cfg = config_at(base, dt, by_dt[dt])
                seeds = sorted(by_seed)
                states = [matched_state(cfg, by_seed[s], initial=it == 0, env=env) for s in seeds]
                res = ppo_gradsnr.measure_many(cfg, states, batches=batches, seed=1, warmup=warmup, env=env)
                done += [{"seed": s, "iteration": it, "control_dt": dt, "arm": arm,
                          **{k: r[k] for k in COLUMNS[4:]}} for s, r in zip(seeds, res)]
                store.write_csv(path, COLUMNS, done)
    return done
