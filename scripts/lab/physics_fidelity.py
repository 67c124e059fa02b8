"""Fidelity of cheaper physics options of the Half-Cheetah against the reference physics.

Reference: the MJCF's physics (timestep 0.005 s, Newton, iterations 4, ls_iterations 4).
Candidates: (A) solver_iterations=2; (B) solver_iterations=2, ls_iterations=2; (C) timestep=0.01
(2 substeps per 0.02 s control step). A "noise floor" is the reference itself started with one hinge
(qpos[3], joint 3) perturbed by ``--perturb`` rad: what chaos alone does to the comparisons.
Every env runs with ``stop_prob=0`` and ``auto_reset=False`` (a trial never stops), from reset.

Checks, each option against the reference:

1. open loop: one fixed action sequence (AR(1) noise of the paper, alpha = 0.8, unit variance,
   clipped to [-2, 2], ``--open-seconds``) from the same start; at 1 s, 2 s and 5 s the RMS over
   time (up to then) of |trunk position difference| (hip x and height: qpos[0], qpos[1]) and the
   max over time and the 6 hinges of |joint-angle difference|;
2. standing: zero action for ``--stand-seconds`` (the PD torque holds the pose): the option's own
   hip-x drift, the difference of its final hip x / height / joint angles from the reference's;
3. trained policy (``--run-dir``, deterministic mean action, ``--policy-seconds`` from reset): mean
   reward per step and mean forward speed vs the reference. The rollout has no randomness (reset is
   deterministic, the policy is the mean, trials never stop), so one rollout per option suffices;
4. speed: an env-only ``jit`` of a ``lax.scan`` of ``vmap(env.step)`` (batch ``--timing-batch``,
   ``--timing-steps`` steps, N(0,1) actions), median of ``--timing-repeats`` timed calls after a
   warm-up; the options' calls are interleaved so a changing machine load hits them alike.

Decision rule: a candidate "changes the robot's behaviour measurably" if
  * its trained-policy forward speed or mean reward differs from the reference's by > 5 % relative, or
  * its standing drift from the reference (distance of the final hip (x, height)) exceeds 1 cm, or
  * its open-loop deviation at 1 s (trunk RMS or max joint-angle difference) exceeds 10x the
    noise floor's.

Prints a markdown table and the verdicts; writes JSON to ``--out`` (atomically).

    python scripts/lab/physics_fidelity.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from nmrl.paper import networks, noise
from nmrl.runs import checkpoint, store
from nmrl.paper.env import ACT_DIM, EnvConfig, HalfCheetah
from nmrl.paper.robot import kinematics, observation

CANDIDATES = {
    "A: iter 2": {"solver_iterations": 2},
    "B: iter 2, ls 2": {"solver_iterations": 2, "ls_iterations": 2},
    "C: dt 0.01": {"timestep": 0.01},
}
#: ``--physics-c``: MuJoCo C inside the program (nmrl/physics/mujoco_c.py) against the MJX reference
C_CANDIDATES = {"D: MuJoCo C": {"physics": "c"}}
REFERENCE = "reference"
NOISE_FLOOR = "noise floor"
HORIZONS_S = (1.0, 2.0, 5.0)
PERTURBED_QPOS = 3  # the first hinge in qpos order (joint 3)
AR_ALPHA = 0.8
ACTION_CLIP = 2.0
# decision thresholds
REL_TOL = 0.05
STAND_TOL_M = 0.01
FLOOR_FACTOR = 10.0

ROOT = pathlib.Path(__file__).resolve().parents[2]
#: a published Fig. 3 point (its compact continuation state; nmrl eval reads it): the paper-scale
#: sweep's best l = 10 seed at 10^5 trials, whose gait is published; the table in docs/performance.md
#: is measured on it.
DEFAULT_RUN = ROOT / "results" / "fig3_paper" / "points" / "l10_s2"
DEFAULT_OUT = ROOT / "results" / "physics_fidelity" / "fidelity.json"
C_OUT = ROOT / "results" / "physics_c" / "fidelity.json"
#: a trajectory has parted from the reference once its trunk is this far from it [m] or a joint angle [rad]
PARTED_M, PARTED_RAD = 0.01, 0.01
QUICK_OUT = ROOT / "results" / "physics_fidelity" / "fidelity_quick.json"


# ----------------------------------------------------------------------------- arguments


def _positive(kind):
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got {text!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
        return v

    return parse


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--physics-c", action="store_true",
                   help=f"the candidate is MuJoCo C (--physics c) instead of the cheaper MJX options "
                        f"(writes {C_OUT.relative_to(ROOT)} by default)")
    p.add_argument("--quick", action="store_true",
                   help="a short test: 1 s rollouts, small timing (writes fidelity_quick.json by default)")
    p.add_argument("--run-dir", type=pathlib.Path, default=DEFAULT_RUN, help="trained policy (run directory)")
    p.add_argument("--seed", type=int, default=0, help="seed of the open-loop action sequence")
    p.add_argument("--perturb", type=_positive(float), default=1e-6, help="noise-floor hinge perturbation [rad]")
    p.add_argument("--open-seconds", type=_positive(float), default=5.0)
    p.add_argument("--stand-seconds", type=_positive(float), default=10.0)
    p.add_argument("--policy-seconds", type=_positive(float), default=10.0)
    p.add_argument("--timing-batch", type=_positive(int), default=32)
    p.add_argument("--timing-steps", type=_positive(int), default=100)
    p.add_argument("--timing-repeats", type=_positive(int), default=5)
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help=f"JSON output (default {DEFAULT_OUT.relative_to(ROOT)}, with --quick "
                        f"{QUICK_OUT.relative_to(ROOT)})")
    a = p.parse_args(argv)
    if a.quick:
        a.open_seconds = a.stand_seconds = a.policy_seconds = 1.0
        a.timing_batch, a.timing_steps, a.timing_repeats = 4, 10, 2
    if a.out is None:
        a.out = C_OUT if a.physics_c and not a.quick else QUICK_OUT if a.quick else DEFAULT_OUT
    if not (a.run_dir / "checkpoints").is_dir() and not checkpoint.has_compact(a.run_dir):
        p.error(f"--run-dir {a.run_dir}: neither a checkpoints/ folder nor a compact.npz (give a training "
                f"run directory or a published point, e.g. results/fig3_paper/points/l10_s0)")
    if a.out.exists() and a.out.is_dir():
        p.error(f"--out {a.out} is a directory")
    return a


# ----------------------------------------------------------------------------- rollouts


def make_env(control_dt: float, **physics) -> HalfCheetah:
    return HalfCheetah(EnvConfig(control_dt=control_dt, stop_prob=0.0, auto_reset=False, **physics))


def start_state(env: HalfCheetah, dq: jax.Array):
    """The reset state with ``dq`` (9,) added to qpos (observation recomputed)."""
    s = env.reset(jax.random.PRNGKey(0))
    data = s.data.replace(qpos=s.data.qpos + dq)
    p, v, phi, dphi = kinematics(data.qpos, data.qvel)
    return s.replace(data=data, obs=observation(p, v, phi, dphi, env.config.contact_tol))


def make_trials(env: HalfCheetah, actor, n_steps: int):
    """jit (theta, dq (B,9), actions (B,T,6), use_policy (B,)) -> per-step qpos, reward, speed, nonfinite.

    Action at step t: use_policy * actor(obs_t) + actions[t]; one compiled program serves the
    open-loop, standing and policy trials of an option (a batch of them under vmap).
    """

    def one(theta, dq, actions, use_policy):
        def body(s, a):
            s = env.step(s, use_policy * actor.apply(theta, s.obs) + a)
            return s, (s.data.qpos, s.reward, s.metrics["forward_speed"], s.metrics["nonfinite"])

        s0 = start_state(env, dq)
        _, (qpos, reward, speed, nonfinite) = jax.lax.scan(body, s0, actions, length=n_steps)
        return {"qpos": jnp.concatenate([s0.data.qpos[None], qpos]), "reward": reward,
                "forward_speed": speed, "nonfinite": nonfinite}

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0, 0)))


def make_timed(env: HalfCheetah, batch: int, steps: int):
    """(jitted scan of vmap(env.step), its arguments) for the speed measurement."""
    states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(1), batch))
    actions = jax.random.normal(jax.random.PRNGKey(2), (steps, batch, ACT_DIM), jnp.float32)

    def run(s, acts):
        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, s.reward

        s, r = jax.lax.scan(body, s, acts)
        return s.data.qpos, r.sum(0)

    return jax.jit(run), (states, actions)


# ----------------------------------------------------------------------------- measures


def open_loop_deviation(q: np.ndarray, q_ref: np.ndarray, steps_at: dict[str, int]) -> dict:
    """Trunk RMS [m] and max joint-angle difference [rad] up to each horizon (q: (T+1, 9))."""
    trunk = np.linalg.norm(q[1:, :2] - q_ref[1:, :2], axis=1)
    joints = np.max(np.abs(q[1:, 3:] - q_ref[1:, 3:]), axis=1)
    return {h: {"trunk_rms_m": float(np.sqrt(np.mean(trunk[:n] ** 2))),
                "joint_max_rad": float(np.max(joints[:n]))} for h, n in steps_at.items()}


def parted_after(q: np.ndarray, q_ref: np.ndarray, dt: float) -> float | None:
    """Seconds until the trunk is PARTED_M from the reference or a joint PARTED_RAD (None: never)."""
    far = (np.linalg.norm(q[1:, :2] - q_ref[1:, :2], axis=1) > PARTED_M) | \
        (np.max(np.abs(q[1:, 3:] - q_ref[1:, 3:]), axis=1) > PARTED_RAD)
    return float((np.argmax(far) + 1) * dt) if far.any() else None


def standing(q: np.ndarray, q_ref: np.ndarray) -> dict:
    fin, ref = q[-1], q_ref[-1]
    return {
        "own_x_drift_m": float(fin[0] - q[0, 0]),
        "final_height_m": float(fin[1]),
        "dx_vs_ref_m": float(fin[0] - ref[0]),
        "dheight_vs_ref_m": float(fin[1] - ref[1]),
        "drift_vs_ref_m": float(np.hypot(fin[0] - ref[0], fin[1] - ref[1])),
        "joint_max_vs_ref_rad": float(np.max(np.abs(fin[3:] - ref[3:]))),
        "final_joints_rad": [float(v) for v in fin[3:]],
    }


def policy_summary(t: dict, n: int) -> dict:
    return {"avg_reward": float(np.mean(t["reward"][:n], dtype=np.float64)),
            "forward_speed": float(np.mean(t["forward_speed"][:n], dtype=np.float64)),
            "nonfinite_steps": int(np.sum(t["nonfinite"][:n] > 0))}


def _finite(obj):
    """The JSON-able copy of ``obj`` with non-finite floats as None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _rel(x: float, ref: float) -> float:
    return (x - ref) / abs(ref) if ref != 0 else math.inf


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    config, theta, _ = checkpoint.restore_policy(args.run_dir)
    dt = float(config.environment.control_dt)
    actor = networks.make_actor(int(config.hidden_actor), ACT_DIM, getattr(config, "arctan", "xla"))
    n_open, n_stand, n_pol = (max(1, round(s / dt)) for s in (args.open_seconds, args.stand_seconds,
                                                                 args.policy_seconds))
    n_steps = max(n_open, n_stand, n_pol)
    steps_at = {f"{h:g}s": round(h / dt) for h in HORIZONS_S if round(h / dt) <= n_open}
    if not steps_at:
        steps_at = {f"{n_open * dt:g}s": n_open}
    first_horizon = next(iter(steps_at))

    # the three trials (open loop, standing, policy) as one batch; the noise floor adds three more
    ar = noise.piecewise_ar(jax.random.PRNGKey(args.seed), n_steps, ACT_DIM, AR_ALPHA, n_steps)
    open_actions = jnp.clip(ar, -ACTION_CLIP, ACTION_CLIP)
    zeros = jnp.zeros_like(open_actions)
    acts3, pol3 = jnp.stack([open_actions, zeros, zeros]), jnp.array([0.0, 0.0, 1.0])
    dq = jnp.zeros((9,)).at[PERTURBED_QPOS].set(args.perturb)

    candidates = C_CANDIDATES if args.physics_c else CANDIDATES
    options = {REFERENCE: {}, **candidates}
    results, timers, compile_s = {}, {}, {}
    for name, physics in options.items():
        t0 = time.perf_counter()
        env = make_env(dt, **physics)
        trials = make_trials(env, actor, n_steps)
        if name == REFERENCE:
            out = trials(theta, jnp.concatenate([jnp.zeros((3, 9)), jnp.tile(dq, (3, 1))]),
                         jnp.concatenate([acts3, acts3]), jnp.concatenate([pol3, pol3]))
        else:
            out = trials(theta, jnp.zeros((3, 9)), acts3, pol3)
        out = {k: np.asarray(v) for k, v in jax.device_get(out).items()}
        split = lambda i: {k: v[i] for k, v in out.items()}  # noqa: E731
        results[name] = [split(i) for i in range(3)]
        if name == REFERENCE:
            results[NOISE_FLOOR] = [split(i) for i in range(3, 6)]
        fn, fargs = make_timed(env, args.timing_batch, args.timing_steps)
        jax.block_until_ready(fn(*fargs))  # compile + warm-up
        timers[name] = (fn, fargs, env.n_substeps)
        compile_s[name] = time.perf_counter() - t0
        print(f"[{name}] rollouts + compile {compile_s[name]:.1f} s", flush=True)

    times = {name: [] for name in timers}
    for _ in range(args.timing_repeats):
        for name, (fn, fargs, _) in timers.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*fargs))
            times[name].append(time.perf_counter() - t0)

    ref_open, ref_stand, ref_pol = results[REFERENCE]
    ref_policy = policy_summary(ref_pol, n_pol)
    ref_time = statistics.median(times[REFERENCE])
    rows = {}
    for name in (REFERENCE, NOISE_FLOOR, *candidates):
        o, st, po = results[name]
        row = {
            "physics": options.get(name, {}),
            "open_loop": open_loop_deviation(o["qpos"][: n_open + 1], ref_open["qpos"][: n_open + 1], steps_at),
            "open_loop_nonfinite_steps": int(np.sum(o["nonfinite"][:n_open] > 0)),
            "open_loop_parted_after_s": parted_after(o["qpos"][: n_open + 1], ref_open["qpos"][: n_open + 1], dt),
            "standing": standing(st["qpos"][: n_stand + 1], ref_stand["qpos"][: n_stand + 1]),
            "standing_nonfinite_steps": int(np.sum(st["nonfinite"][:n_stand] > 0)),
            "policy": policy_summary(po, n_pol),
        }
        row["policy"]["reward_rel"] = _rel(row["policy"]["avg_reward"], ref_policy["avg_reward"])
        row["policy"]["speed_rel"] = _rel(row["policy"]["forward_speed"], ref_policy["forward_speed"])
        if name in timers:
            med = statistics.median(times[name])
            row["timing"] = {"median_s": med, "all_s": times[name], "speedup_vs_ref": ref_time / med,
                             "control_steps_per_s": args.timing_batch * args.timing_steps / med,
                             "substeps": timers[name][2]}
        rows[name] = row

    floor = rows[NOISE_FLOOR]["open_loop"][first_horizon]
    verdicts = {}
    for name in candidates:
        r = rows[name]
        dev = r["open_loop"][first_horizon]
        reasons = []
        if abs(r["policy"]["speed_rel"]) > REL_TOL:
            reasons.append(f"policy speed {100 * r['policy']['speed_rel']:+.1f}%")
        if abs(r["policy"]["reward_rel"]) > REL_TOL:
            reasons.append(f"policy reward {100 * r['policy']['reward_rel']:+.1f}%")
        if r["standing"]["drift_vs_ref_m"] > STAND_TOL_M:
            reasons.append(f"standing drift {1000 * r['standing']['drift_vs_ref_m']:.1f} mm")
        for key, label in (("trunk_rms_m", "trunk RMS"), ("joint_max_rad", "joint max")):
            ratio = dev[key] / floor[key] if floor[key] > 0 else math.inf
            r["open_loop"][f"{first_horizon}_{key}_vs_floor"] = ratio
            if ratio > FLOOR_FACTOR:
                reasons.append(f"open-loop {label} @{first_horizon} = {ratio:.0f}x noise floor")
        r["changes_behaviour"] = bool(reasons)
        r["reasons"] = reasons
        verdicts[name] = reasons

    print_table(rows, steps_at, ref_policy)
    print()
    for name, reasons in verdicts.items():
        verdict = "CHANGES the robot's behaviour measurably" if reasons else "no measurable change"
        print(f"- {name}: {verdict}" + (f" ({'; '.join(reasons)})" if reasons else ""))

    result = {
        "what": "physics fidelity of candidate env options vs the reference (scripts/lab/physics_fidelity.py)",
        "quick": bool(args.quick),
        "run_dir": str(args.run_dir),
        "control_dt": dt,
        "seed": args.seed,
        "perturb_rad": args.perturb,
        "perturbed_qpos_index": PERTURBED_QPOS,
        "open_loop_actions": {"alpha": AR_ALPHA, "clip": ACTION_CLIP, "steps": n_open},
        "standing_steps": n_stand,
        "policy_steps": n_pol,
        "timing": {"batch": args.timing_batch, "steps": args.timing_steps, "repeats": args.timing_repeats,
                   "backend": jax.default_backend(), "machine": platform.node(),
                   "load_avg": os.getloadavg()},
        "parted": {"trunk_m": PARTED_M, "joint_rad": PARTED_RAD},
        "decision_rule": {"policy_rel_tol": REL_TOL, "standing_drift_m": STAND_TOL_M,
                          "open_loop_floor_factor": FLOOR_FACTOR, "open_loop_horizon": first_horizon},
        "options": rows,
        "compile_and_rollout_s": compile_s,
        "versions": {"jax": jax.__version__},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    store.atomic_write_text(args.out, json.dumps(_finite(result), indent=2, allow_nan=False) + "\n")
    print(f"\nwrote {args.out}")
    return result


def print_table(rows: dict, steps_at: dict, ref_policy: dict) -> None:
    hs = list(steps_at)
    head = (["option"] + [f"trunk RMS @{h} [mm]" for h in hs] + [f"joint max @{h} [mrad]" for h in hs]
            + ["stand: own x drift [mm]", "stand: Δx / Δh vs ref [mm]", "stand: Δjoint vs ref [mrad]",
               "policy reward (rel)", "policy speed m/s (rel)", "step time [ms] (speedup)"])
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, r in rows.items():
        ol, st, po = r["open_loop"], r["standing"], r["policy"]
        cells = [name]
        cells += [f"{1000 * ol[h]['trunk_rms_m']:.3g}" for h in hs]
        cells += [f"{1000 * ol[h]['joint_max_rad']:.3g}" for h in hs]
        cells += [f"{1000 * st['own_x_drift_m']:+.2f}",
                  f"{1000 * st['dx_vs_ref_m']:+.2f} / {1000 * st['dheight_vs_ref_m']:+.2f}",
                  f"{1000 * st['joint_max_vs_ref_rad']:.3g}",
                  f"{po['avg_reward']:.3f} ({100 * po['reward_rel']:+.1f}%)",
                  f"{po['forward_speed']:.3f} ({100 * po['speed_rel']:+.1f}%)"]
        t = r.get("timing")
        cells.append(f"{1000 * t['median_s']:.0f} ({t['speedup_vs_ref']:.2f}x)" if t else "(= reference)")
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
