"""Throughput of the batched MJX Half-Cheetah vs MuJoCo C (``mujoco.rollout``), 1 vs 2 CPU devices.

Run: ``python benchmarks/bench_env.py [--quick] [--out results/benchmarks/env.json]``

* MJX: ``jit`` of a ``lax.scan`` over T control steps of ``vmap(env.step)`` with random actions
  (a ~ N(0, 1), a^0 = 0.1 a as in Sec. V-C); compile time (first call) apart from the steady state
  (best of a few repeats). One control step = ``env.n_substeps`` physics steps (4 by default).
* MuJoCo C: ``mujoco.rollout.rollout`` on the same MJCF/options, the same batch, open-loop random
  ctrl uniform in [-T_i, T_i] (the magnitude of the paper's torques), nthread = 1 and os.cpu_count().
* Devices: every MJX measurement runs in a subprocess, once with 1 host device and once with
  ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` and the batch split over the 2 devices
  (several ways of splitting it; see docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODES = ("single", "jit_sharded", "shard_map_naive", "shard_map", "pmap")


# ----------------------------------------------------------------------------- MJX (worker side)


def _mjx_worker(batch_sizes, mode: str, steps_per_call: int, repeats: int, iterations=None) -> dict:
    """Measure MJX in this process (its XLA_FLAGS decide the device count)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

    from nmrl.paper.env import EnvConfig, HalfCheetah
    from nmrl.runs.sharding import shard_batch

    t0 = time.perf_counter()
    env = HalfCheetah(EnvConfig(solver_iterations=iterations, ls_iterations=iterations))
    t_env = time.perf_counter() - t0
    devs = jax.local_devices()
    nd = len(devs)
    mesh = Mesh(np.array(devs), ("b",))
    shard = NamedSharding(mesh, P("b"))

    def local_rollout(states, akeys, T):
        def body(carry, _):
            s, k = carry
            k, sub = jax.vmap(jax.random.split, out_axes=1)(k)
            a = jax.vmap(lambda kk: jax.random.normal(kk, (6,)))(sub)
            s = jax.vmap(env.step)(s, a)
            return (s, k), s.reward
        (s, k), r = jax.lax.scan(body, (states, akeys), None, length=T)
        return s, k, r.sum(0)

    out = []
    for B in batch_sizes:
        T = max(steps_per_call // B, 8)
        keys = jax.random.split(jax.random.key(0), B)
        akeys = jax.random.split(jax.random.key(1), B)
        states = jax.jit(jax.vmap(env.reset))(keys)
        if mode == "single":
            f = jax.jit(lambda s, k: local_rollout(s, k, T))
        elif mode == "jit_sharded":  # GSPMD: jit with sharded inputs
            states, akeys = shard_batch((states, akeys), mesh)
            f = jax.jit(lambda s, k: local_rollout(s, k, T))
        elif mode == "shard_map_naive":  # every leaf P("b"): zero-size leaves come back replicated
            states, akeys = jax.device_put((states, akeys), shard)
            f = jax.jit(jax.shard_map(lambda s, k: local_rollout(s, k, T), mesh=mesh,
                                      in_specs=(P("b"), P("b")), out_specs=(P("b"), P("b"), P("b")),
                                      check_vma=False))
        elif mode == "shard_map":  # nmrl.runs.sharding: zero-size leaves replicated up front
            states, akeys = shard_batch((states, akeys), mesh)
            f = jax.jit(jax.shard_map(lambda s, k: local_rollout(s, k, T), mesh=mesh,
                                      in_specs=(P("b"), P("b")), out_specs=(P("b"), P("b"), P("b")),
                                      check_vma=False))
        elif mode == "pmap":
            resh = lambda x: x.reshape((nd, x.shape[0] // nd) + x.shape[1:])  # noqa: E731
            states, akeys = jax.tree.map(resh, (states, akeys))
            f = jax.pmap(lambda s, k: local_rollout(s, k, T))
        else:
            raise ValueError(mode)
        t0 = time.perf_counter()
        states, akeys, r = jax.block_until_ready(f(states, akeys))
        t_first = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            states, akeys, r = jax.block_until_ready(f(states, akeys))
            times.append(time.perf_counter() - t0)
        best = min(times)
        n_compiled = f._cache_size() if hasattr(f, "_cache_size") else None
        out.append({
            "batch": B, "T": T, "mode": mode, "devices": nd, "first_call_s": t_first,
            "compile_s": max(t_first - best, 0.0), "best_s": best, "times_s": times,
            "control_steps_per_s": B * T / best,
            "physics_steps_per_s": B * T * env.n_substeps / best,
            "reward_finite": bool(np.all(np.isfinite(np.asarray(r)))), "n_compiled": n_compiled,
        })
        print(json.dumps(out[-1]), file=sys.stderr, flush=True)
    return {"env_init_s": t_env, "n_substeps": env.n_substeps, "results": out}


def mjx_subprocess(batch_sizes, mode: str, ndev: int, steps_per_call: int, repeats: int,
                   xla_extra: str = "", iterations=None, timeout: float = 3600) -> dict:
    """Run :func:`_mjx_worker` in a fresh interpreter with ``ndev`` host devices."""
    env = dict(os.environ)
    env["JAX_PLATFORMS"] = "cpu"
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    flags = f"--xla_force_host_platform_device_count={ndev} {xla_extra}".strip()
    env["XLA_FLAGS"] = flags
    from nmrl.runs import devices  # the thread pool nmrl's own commands give ndev devices

    if (pool := devices.pool_threads(ndev)) is not None:
        env["PJRT_NPROC"] = str(pool)
    cmd = [sys.executable, str(pathlib.Path(__file__).resolve()), "--worker", "--mode", mode,
           "--batch", *map(str, batch_sizes), "--steps-per-call", str(steps_per_call),
           "--repeats", str(repeats)]
    if iterations is not None:
        cmd += ["--iterations", str(iterations)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
        stdout, stderr, rc = p.stdout, p.stderr, p.returncode
    except subprocess.TimeoutExpired as e:  # a worker that never ends still reports what it measured
        stdout, stderr, rc = "", (e.stderr or b"").decode(errors="replace"), "timeout"
    if rc != 0 or not stdout.strip():
        # keep what the worker measured before it failed (one JSON line per batch size on stderr)
        done = [json.loads(l) for l in stderr.splitlines() if l.startswith('{"batch"')]
        return {"xla_flags": flags, "error": f"worker rc={rc} after {len(done)} batch sizes "
                f"(timeout {timeout} s)", "stderr_tail": stderr[-1500:], "results": done}
    res = json.loads(stdout.strip().splitlines()[-1])
    res["xla_flags"] = flags
    return res


# ------------------------------------------------------------------------------------ MuJoCo C


def c_rollout(batch_sizes, nstep_control: int, nthreads, repeats: int = 3) -> list[dict]:
    """MuJoCo C on the same MJCF via mujoco.rollout; ``nstep_control`` control steps per trajectory."""
    import mujoco
    import numpy as np
    from mujoco import rollout

    from nmrl.paper.env import MODEL_PATH, EnvConfig

    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    n_sub = int(round(EnvConfig().control_dt / m.opt.timestep))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.zeros(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, x0, spec)
    strength = m.actuator_forcerange[:, 1]
    rng = np.random.default_rng(0)
    out = []
    for nthread in nthreads:
        datas = [mujoco.MjData(m) for _ in range(nthread)]
        for B in batch_sizes:
            nstep = max(nstep_control // B, 8) * n_sub
            ctrl = rng.uniform(-1, 1, (B, nstep, m.nu)) * strength
            init = np.tile(x0, (B, 1))
            times = []
            for _ in range(repeats + 1):
                t0 = time.perf_counter()
                rollout.rollout(m, datas, init, ctrl, persistent_pool=True)
                times.append(time.perf_counter() - t0)
            best = min(times[1:])
            out.append({"batch": B, "nthread": nthread, "nstep": nstep, "best_s": best,
                        "physics_steps_per_s": B * nstep / best,
                        "control_steps_per_s": B * nstep / n_sub / best})
            print(json.dumps(out[-1]), file=sys.stderr, flush=True)
    return out



# ------------------------------------------------------------------------ physics-option study


def _c_closed_loop(m, actions, record_every: int):
    """C MuJoCo with the env's control law (Sec. V-A torque recomputed every substep).

    actions: (T, 6) in the env's action order (joints 1, 2, 3, 6, 7, 8). Returns dict of arrays
    sampled at the control steps: joint positions (T, 10, 2), min joint height so far.
    """
    import mujoco
    import numpy as np

    act = (1, 2, 3, 6, 7, 8)
    n_sub = int(round(0.02 / m.opt.timestep))
    qadr = np.array([m.joint(f"j{i}").qposadr[0] for i in act])
    dadr = np.array([m.joint(f"j{i}").dofadr[0] for i in act])
    aidx = np.array([m.actuator(f"m{i}").id for i in act])
    strength = np.array([60.0, 90.0, 120.0, 90.0, 60.0, 30.0])
    sid = np.array([m.site(f"joint{i}").id for i in range(10)])
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    pos, minz = [], []
    lowest = np.inf
    for a in actions:
        for _ in range(n_sub):
            tau0 = 2 / np.pi * np.arctan(-2 * d.qpos[qadr] - 0.05 * d.qvel[dadr])
            d.ctrl[aidx] = strength * np.clip(tau0 + 0.1 * a, -1, 1)
            mujoco.mj_step(m, d)
            lowest = min(lowest, d.site_xpos[sid, 2].min())
        mujoco.mj_kinematics(m, d)
        pos.append(d.site_xpos[sid][:, [0, 2]].copy())
        minz.append(lowest)
    pos = np.array(pos)
    return {"pos": pos, "minz": np.array(minz), "finite": bool(np.all(np.isfinite(pos)))}


def physics_options_study(n_seeds: int = 8, seconds: float = 2.0) -> dict:
    """Trajectories under zero / random / saturating random actions vs a fine reference (C MuJoCo).

    Reference: timestep 0.00125 s, 50 solver iterations. Each setting: timestep in {0.01, 0.005,
    0.0025} x iterations (= ls_iterations) in {1, 2, 4, 8}. Errors are RMS joint-position
    differences [m] to the reference at 0.5 s and 1 s (random actions diverge chaotically later),
    and the trunk height / forward displacement after 4 s of zero action.
    """
    import mujoco
    import numpy as np

    from nmrl.paper.env import MODEL_PATH

    T = int(round(seconds / 0.02))
    rng = np.random.default_rng(0)
    scen = {
        "zero_4s": [np.zeros((200, 6))],
        "random_N01": [rng.normal(size=(T, 6)) for _ in range(n_seeds)],
        "random_U10": [rng.uniform(-10, 10, size=(T, 6)) for _ in range(n_seeds)],
    }

    def model(ts, it):
        m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
        m.opt.timestep, m.opt.iterations, m.opt.ls_iterations = ts, it, it
        return m

    def runs(m):
        return {k: [_c_closed_loop(m, a, 1) for a in v] for k, v in scen.items()}

    t0 = time.perf_counter()
    ref = runs(model(0.00125, 50))
    out = {"reference": {"timestep": 0.00125, "iterations": 50}, "settings": []}
    for ts in (0.01, 0.005, 0.0025):
        for it in (1, 2, 4, 8):
            m = model(ts, it)
            t1 = time.perf_counter()
            r = runs(m)
            wall = time.perf_counter() - t1
            row = {"timestep": ts, "iterations": it, "c_wall_s": wall}
            for k in scen:
                errs = []
                for a, b in zip(r[k], ref[k]):
                    e = np.sqrt(np.mean((a["pos"] - b["pos"]) ** 2, axis=(1, 2)))
                    errs.append(e)
                errs = np.array(errs)
                row[k] = {
                    "rms_err_0.5s": float(errs[:, 24].mean()),
                    "rms_err_1s": float(errs[:, 49].mean()),
                    "min_joint_height": float(min(x["minz"][-1] for x in r[k])),
                    "finite": all(x["finite"] for x in r[k]),
                }
                if k == "zero_4s":
                    p = r[k][0]["pos"]
                    pr = ref[k][0]["pos"]
                    row[k]["trunk_height_4s"] = float((p[-1, 3, 1] + p[-1, 4, 1]) / 2)
                    row[k]["ref_trunk_height_4s"] = float((pr[-1, 3, 1] + pr[-1, 4, 1]) / 2)
                    row[k]["x_drift_4s"] = float(p[-1, 3, 0] - p[0, 3, 0])
                    row[k]["max_err_4s"] = float(errs[0].max())
            out["settings"].append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    out["study_wall_s"] = time.perf_counter() - t0
    return out


def machine() -> dict:
    import jax
    import mujoco

    cpu = ""
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu_count": os.cpu_count(), "cpu": cpu, "platform": platform.platform(),
            "python": platform.python_version(), "jax": jax.__version__, "mujoco": mujoco.__version__,
            "load_avg_at_start": os.getloadavg()}


def run(quick: bool, extras: bool = True, worker_timeout: float = 900) -> dict:
    """All measurements; returns the JSON-able dict (see the module docstring)."""
    sizes = [64, 256] if quick else [64, 256, 1024, 4096]
    spc = 2048 if quick else 16384  # control steps (batch x T) per timed call
    rep = 2 if quick else 3
    out = {"machine": machine(), "quick": quick, "batch_sizes": sizes, "mjx": {}, "c": None}
    t0 = time.perf_counter()
    out["mjx"]["1dev_single"] = mjx_subprocess(sizes, "single", 1, spc, rep, timeout=worker_timeout)
    out["mjx"]["2dev_shard_map"] = mjx_subprocess(sizes, "shard_map", 2, spc, rep, timeout=worker_timeout)
    if not quick and extras:  # the other ways of using 2 devices, at one batch size
        out["mjx"]["2dev_single_unsharded"] = mjx_subprocess([256], "single", 2, spc, rep)
        for mode in ("jit_sharded", "shard_map_naive", "pmap"):
            out["mjx"][f"2dev_{mode}"] = mjx_subprocess([256], mode, 2, spc, rep, timeout=worker_timeout)
        for it in (1, 2, 8):  # solver iterations (the MJCF's default is 4)
            out["mjx"][f"1dev_single_iter{it}"] = mjx_subprocess([256], "single", 1, spc, rep, iterations=it,
                                                                  timeout=worker_timeout)
    ncpu = os.cpu_count() or 1
    out["c"] = c_rollout(sizes, spc, sorted({1, ncpu}), repeats=rep)
    # ratios MJX / C (physics steps per second), best MJX vs best C at each batch size
    ratio = {}
    for B in sizes:
        mj = {k: r["physics_steps_per_s"] for k, v in out["mjx"].items()
              if k in ("1dev_single", "2dev_shard_map") for r in v["results"] if r["batch"] == B}
        cc = {f"nthread{r['nthread']}": r["physics_steps_per_s"] for r in out["c"] if r["batch"] == B}
        ratio[str(B)] = {f"{a}/{b}": mj[a] / cc[b] for a in mj for b in cc}
    out["ratio_mjx_over_c"] = ratio
    out["total_wall_s"] = time.perf_counter() - t0
    return out


def plot(res: dict, path: pathlib.Path) -> None:
    from nmrl.analysis.plots import plt, save

    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label, st in (("1dev_single", "MJX, 1 CPU device", "o-"),
                           ("2dev_shard_map", "MJX, 2 CPU devices (shard_map)", "s-")):
        r = res["mjx"][key]["results"]
        if r:
            ax.plot([x["batch"] for x in r], [x["physics_steps_per_s"] for x in r], st, label=label)
    for nt in sorted({r["nthread"] for r in res["c"]}):
        r = [x for x in res["c"] if x["nthread"] == nt]
        ax.plot([x["batch"] for x in r], [x["physics_steps_per_s"] for x in r], "^--",
                label=f"MuJoCo C rollout, {nt} thread{'s' if nt > 1 else ''}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("batch size (environments)")
    ax.set_ylabel("physics steps / s (timestep 0.005 s)")
    m = res["machine"]
    ax.set_title(f"Half-Cheetah throughput, {m['cpu_count']} CPU cores, jax {m['jax']}, mujoco {m['mujoco']}",
                 fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save(fig, path, dpi=120)


def _worker_main(args) -> None:
    res = _mjx_worker(args.batch, args.mode, args.steps_per_call, args.repeats, args.iterations)
    print(json.dumps(res))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="batch sizes 64, 256 only; fewer steps")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks" / "env.json"))
    ap.add_argument("--physics", action="store_true",
                    help="run the physics-option study (timestep x solver iterations) instead")
    ap.add_argument("--no-extras", action="store_true",
                    help="skip the other 2-device modes and the solver-iteration runs (batch 256)")
    ap.add_argument("--worker-timeout", type=float, default=900, help="seconds per MJX subprocess")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--mode", default="single", choices=MODES, help=argparse.SUPPRESS)
    ap.add_argument("--batch", type=int, nargs="+", default=[64], help=argparse.SUPPRESS)
    ap.add_argument("--steps-per-call", type=int, default=8192, help=argparse.SUPPRESS)
    ap.add_argument("--repeats", type=int, default=3, help=argparse.SUPPRESS)
    ap.add_argument("--iterations", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        _worker_main(args)
        return
    if args.physics:
        res = physics_options_study()
        print(json.dumps(res, indent=1))  # summarised in docs/model.md ("Physics options")
        return
    res = run(args.quick, extras=not args.no_extras, worker_timeout=args.worker_timeout)
    print(json.dumps(res, indent=1))
    out = pathlib.Path(args.out)
    out.write_text(json.dumps(res, indent=1))
    if not args.quick:
        plot(res, out.with_name("env_throughput.png"))


if __name__ == "__main__":
    main()
