"""The benchmarks' report: the summary of ratios, the markdown table and the throughput figure.

Read from the JSON that ``python -m benchmarks`` writes (benchmarks/__main__.py): each section's
result as its module returns it, a section not run or failed left out.
"""

from __future__ import annotations

import pathlib
import statistics


# ------------------------------------------------------------------------------- summary / table


def _get(d, *keys, default=None):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return default
        d = d[k]
    return d


def summary(res: dict) -> dict:
    s = {}
    env = res.get("env")
    if env and "ratio_mjx_over_c" in env:
        s["env_best_mjx_over_best_c"] = {B: r["best_mjx/best_c"] for B, r in env["ratio_mjx_over_c"].items()}
        s["env_goal_met"] = env.get("goal_met")
    lr = res.get("learning")
    if lr and "results" in lr:
        s["learning_overhead"] = {str(r["batch"]): r["overhead"] for r in lr["results"]}
        s["learning_goal_met"] = lr.get("goal_met")
    sw = res.get("sweep")
    if sw and "sweep_ctrl_steps_per_s" in sw:
        for k in ("sweep_ctrl_steps_per_s", "sweep_speedup_over_single_vmap", "sweep_over_mujoco_c",
                  "hours_for_1e5_trials_x_24_points"):
            s[k] = sw[k]
        s["sweep_compile_s"] = sw["worker"]["new"]["compile_s"]
        s["sweep_goal_met"] = sw.get("goal_met")
    sc = res.get("scaling")
    if sc and "hung_or_failed" in sc:
        s["scaling_2dev_over_1dev"] = sc.get("speedup_2dev_over_1dev")
        s["scaling_hung_or_failed"] = sc.get("hung_or_failed")
    di = res.get("distributed")
    if di and "runs" in di:
        s["distributed_2proc_over_1proc_2dev"] = di.get("two_processes_over_one_process")
    ba = res.get("baseline")
    if ba and "runs" in ba:
        s["baseline_ppo_over_ac_speed"] = ba.get("ppo_over_actor_critic_speed")
        s["baseline_hours_per_1e7_steps"] = ba.get("hours_per_1e7_steps")
    pp = res.get("ppo")
    if pp and "runs" in pp:
        s["ppo_native_over_brax"] = pp.get("native_over_brax")
        s["ppo_native_share_of_iteration"] = _get(pp, "profile", "share_of_iteration")
    pc = res.get("physics_c")
    if pc and "worker" in pc:
        w = pc["worker"]
        s["physics_c_env_over_batch_alone"] = w["a_env"]["ratio"]
        s["physics_c_sweep_over_mjx"] = w["b_sweep"]["c_over_mjx"]
        s["physics_c_sweep_over_mujoco_c"] = w["c_limit"]["sweep_c_over_limit"]
        if "sweep_c_grouped_over_limit" in w["c_limit"]:
            s["physics_c_grouped_sweep_over_mjx"] = w["b_sweep"]["rates"]["c_grouped"] / w["b_sweep"]["rates"]["mjx"]
            s["physics_c_grouped_sweep_over_mujoco_c"] = w["c_limit"]["sweep_c_grouped_over_limit"]
        s["physics_c_ppo_over_mjx"] = {k: v["c_over_mjx"] for k, v in w["d_ppo"].items()}
        if "e_ppo_group" in w:
            s["physics_c_ppo_grouped_over_one_at_a_time"] = w["e_ppo_group"]["grouped_over_one_at_a_time"]
        s["physics_c_goal_met"] = pc.get("goal_met")
    gc = res.get("grad_chunks")
    if gc and "worker" in gc:
        s["grad_chunks_over_whole"] = gc["worker"]["speedup_over_whole"]
    li = res.get("likelihood")
    if li and "results" in li:
        by = {(r["method"], r["l"]): r["median_s"] for r in li["results"]}
        s["likelihood_dense_over_tridiagonal"] = {
            str(l): by[("lr_dense", l)] / by[("lr_tridiagonal", l)] for (m, l) in by if m == "lr_tridiagonal"
            and ("lr_dense", l) in by}
    return s


def _f(x, nd=0, suffix=""):
    if x is None:
        return "–"
    if isinstance(x, float) and abs(x) >= 1000:
        return f"{x:,.0f}{suffix}"
    return f"{x:.{nd}f}{suffix}"


def table(res: dict) -> str:
    rows = [("Benchmark", "Setting", "Candidate", "Baseline", "Ratio", "Compile [s]")]
    env = res.get("env")
    if env and "mjx" in env:
        for B in env["config"]["batches"]:
            mj = {k: next((r for r in v.get("results", []) if r["batch"] == B), None) for k, v in env["mjx"].items()}
            cc = {r["nthread"]: r["physics_steps_per_s"] for r in env["c"] if r["batch"] == B}
            for key, nt, label in (("1dev_single", 1, "1 dev / 1 thread"), ("2dev_shard_map", 2, "2 dev / 2 threads")):
                r = mj.get(key)
                if r is None:
                    err = env["mjx"].get(key, {}).get("error", "no result")
                    rows.append((f"env physics steps/s, B={B}", label, f"failed: {err}", _f(cc.get(nt), 0), "–", "–"))
                    continue
                rows.append((f"env physics steps/s, B={B}", f"MJX {label} vs MuJoCo C",
                             _f(r["physics_steps_per_s"]), _f(cc.get(nt)),
                             _f(r["physics_steps_per_s"] / cc[nt], 2, "×") if nt in cc else "–",
                             _f(r["compile_s"], 1)))
    lr = res.get("learning")
    if lr and "results" in lr:
        for r in lr["results"]:
            rows.append((f"learning ctrl steps/s, B={r['batch']}",
                         f"train chunk vs env-only scan (T={r['chunk_steps']})",
                         _f(r["train"]["control_steps_per_s"]), _f(r["env"]["control_steps_per_s"]),
                         f"{r['train_over_env']:.2f}× (overhead {100 * r['overhead']:.0f}%; "
                         f"{100 * (1 - r['train_over_env_of_medians']):.0f}% from medians)",
                         f"{r['compile_s']['train']:.1f} / {r['compile_s']['env']:.1f}"))
    li = res.get("likelihood")
    if li and "results" in li:
        by = {(r["method"], r["l"]): r for r in li["results"]}
        for l in (max(li["config"]["ls"]),):
            for a, b, what in (("lr_tridiagonal", "lr_dense", "likelihood ratio, actor 31-100-6"),
                               ("tridiagonal", "dense_solve", "(Λ⁻¹⊗Σ⁻¹)u")):
                if (a, l) in by and (b, l) in by:
                    ra, rb = by[(a, l)], by[(b, l)]
                    rows.append((f"likelihood µs/call, l={l}", f"{what}: tridiagonal vs dense",
                                 f"{ra['median_s'] * 1e6:.0f} µs", f"{rb['median_s'] * 1e6:.0f} µs",
                                 f"{rb['median_s'] / ra['median_s']:.1f}× faster",
                                 f"{ra['compile_s']:.1f} / {rb['compile_s']:.1f}"))
    sw = res.get("sweep")
    if sw and "worker" in sw:
        w = sw["worker"]
        a, b = w["new"], w["single_vmap"]
        rows.append(("sweep ctrl steps/s, whole machine",
                     f"{w['points']} points with learning: {w['devices']} dev × lax.map, {a['num_envs_per_point']} "
                     f"envs/point vs 1 vmap on 1 dev, {b['num_envs_per_point']} envs/point",
                     _f(a["control_steps_per_s"]), _f(b["control_steps_per_s"]),
                     _f(sw["sweep_speedup_over_single_vmap"], 2, "×"),
                     f"{a['compile_s']:.1f} / {b['compile_s']:.1f}"))
        rows.append(("sweep vs MuJoCo C, ctrl steps/s",
                     f"the same (with learning) vs mujoco.rollout, {sw['mujoco_c']['nthreads']} threads, B={sw['mujoco_c']['batch']} "
                     f"(physics only); 10⁵ trials × 24 points: {sw['hours_for_1e5_trials_x_24_points']:.1f} h",
                     _f(a["control_steps_per_s"]), _f(sw["mujoco_c"]["control_steps_per_s"]),
                     _f(sw["sweep_over_mujoco_c"], 2, "×"), "–"))
    pc = res.get("physics_c")
    if pc and "worker" in pc:
        w = pc["worker"]
        a, sw, lim = w["a_env"], w["b_sweep"], w["c_limit"]
        rows.append(("C env ctrl steps/s, in the program", f"jit(scan(vmap(step))) vs mujoco.batch alone, B={a['batch']}, "
                     f"{a['threads']} threads", _f(a["in_program"]), _f(a["batch_alone"]), _f(a["ratio"], 2, "×"), "–"))
        rows.append(("sweep ctrl steps/s, --physics c", f"{sw['points']} points with learning, {w['devices']} dev: C vs MJX",
                     _f(sw["rates"]["c"]), _f(sw["rates"]["mjx"]), _f(sw["c_over_mjx"], 2, "×"),
                     f"{sw['compile_s']['c']:.1f} / {sw['compile_s']['mjx']:.1f}"))
        rows.append(("sweep ctrl steps/s, --physics c", f"C on {w['devices']} dev × {w['threads_per_device']} thread vs "
                     f"1 dev × {w['cores']} threads", _f(sw["rates"]["c"]), _f(sw["rates"]["c_one_device"]),
                     _f(sw["rates"]["c"] / sw["rates"]["c_one_device"], 2, "×"), "–"))
        rows.append(("sweep vs MuJoCo C, --physics c", f"the C sweep (with learning) vs mujoco.batch alone, "
                     f"B={lim['batch']}, {lim['threads']} threads", _f(sw["rates"]["c"]), _f(lim["batch_alone"]),
                     _f(lim["sweep_c_over_limit"], 2, "×"), "–"))
        if "c_grouped" in sw["rates"]:
            g = sw["c_grouped_points_per_call"]
            rows.append(("sweep ctrl steps/s, --physics c", f"C with --group {g} (a device's points in one call) vs "
                         "a point at a time", _f(sw["rates"]["c_grouped"]), _f(sw["rates"]["c"]),
                         _f(sw["c_grouped_over_c"], 2, "×"), f"{sw['compile_s']['c_grouped']:.1f} / {sw['compile_s']['c']:.1f}"))
            rows.append(("sweep vs MuJoCo C, --physics c", f"the grouped C sweep vs mujoco.batch alone, "
                         f"B={lim['grouped_batch']}, {lim['threads']} threads", _f(sw["rates"]["c_grouped"]),
                         _f(lim["grouped_batch_alone"]), _f(lim["sweep_c_grouped_over_limit"], 2, "×"), "–"))
        if "c_grouped_xla_arctan" in sw["rates"]:
            rows.append(("sweep ctrl steps/s, --physics c", "the grouped C sweep, the networks' fast arctan vs XLA's "
                         "(--arctan xla)", _f(sw["rates"]["c_grouped"]), _f(sw["rates"]["c_grouped_xla_arctan"]),
                         _f(sw["fast_over_xla_arctan"], 2, "×"), "–"))
        for k, v in w["d_ppo"].items():
            rows.append((f"native PPO ctrl steps/s, {k}", f"one iteration ({v['num_minibatches']} minibatches), "
                         "64 envs, value 2×64: C vs MJX", _f(v["rates"]["c"]), _f(v["rates"]["mjx"]),
                         _f(v["c_over_mjx"], 2, "×"), f"{v['compile_s']['c']:.1f} / {v['compile_s']['mjx']:.1f}"))
        e = w.get("e_ppo_group")
        if e:
            n = e["seeds"]
            rows.append((f"native PPO ctrl steps/s, {e['control_dt'] * 1000:g}ms", f"{n} seeds, C: --group {n} (a device's "
                         f"seeds in one call) vs a seed at a time ({e['num_minibatches']} minibatch)",
                         _f(e["rates"][f"group_{n}"]), _f(e["rates"]["group_1"]), _f(e["grouped_over_one_at_a_time"], 2, "×"),
                         f"{e['compile_s'][f'group_{n}']:.1f} / {e['compile_s']['group_1']:.1f}"))
    gc = res.get("grad_chunks")
    if gc and "worker" in gc:
        w = gc["worker"]
        for k, v in w["speedup_over_whole"].items():
            rows.append((f"native PPO ctrl steps/s, {w['control_dt'] * 1000:g}ms", f"{w['seeds']} seeds grouped, C: each "
                         f"minibatch's gradient in {k.split('_')[1]} parts vs at once ({w['num_minibatches']} "
                         "minibatches)", _f(w["rates"][k]), _f(w["rates"]["chunks_1"]), _f(v, 2, "×"),
                         f"{w['compile_s'][k]:.1f} / {w['compile_s']['chunks_1']:.1f}"))
    sc = res.get("scaling")
    if sc and "two_device_process" in sc:
        two = sc["two_device_process"]
        c = sc["config"]
        setting = f"{c['points']} points × {c['num_envs_per_point']} envs: 2 dev (shard_map) vs 1 dev"
        if "error" in two:
            rows.append(("training ctrl steps/s, devices", setting, f"failed: {two['error']}", "–", "–", "–"))
        else:
            m = two["modes"]
            rows.append(("training ctrl steps/s, devices", setting,
                         _f(m["2dev"]["control_steps_per_s"]), _f(m["1dev"]["control_steps_per_s"]),
                         _f(sc["speedup_2dev_over_1dev"], 2, "×"),
                         f"{m['2dev']['compile_s']:.1f} / {m['1dev']['compile_s']:.1f}"))
    di = res.get("distributed")
    if di and "runs" in di:
        c = di["config"]
        a = [r for r in di["runs"]["two_processes_one_device_each"] if "error" not in r]
        b = [r for r in di["runs"]["one_process_two_devices"] if "error" not in r]
        med = lambda rs, k: statistics.median([r[k] for r in rs if r.get(k) is not None]) if rs else None  # noqa: E731
        rows.append(("nmrl train ctrl steps/s, processes",
                     f"N={c['num_envs']}: 2 processes × 1 dev (jax.distributed, gloo) vs 1 process × 2 dev",
                     _f(med(a, "control_steps_per_s")), _f(med(b, "control_steps_per_s")),
                     _f(di["two_processes_over_one_process"], 2, "×"),
                     f"{_f(med(a, 'compile_s'), 1)} / {_f(med(b, 'compile_s'), 1)}"))
    pp = res.get("ppo")
    if pp and "runs" in pp:
        c = pp["config"]
        bc = [r["compile_s"] for r in pp["runs"]["brax"] if "compile_s" in r]
        rows.append(("PPO ctrl steps/s with learning",
                     f"native vs Brax PPO, N={c['num_envs']}, T={c['unroll_length']}, {c['num_minibatches']}×"
                     f"{c['batch_size']}, {c['epochs']} epochs, 1 dev each",
                     _f(pp["native_control_steps_per_s"]), _f(pp.get("brax_control_steps_per_s")),
                     _f(pp.get("native_over_brax"), 2, "×"),
                     f"{_f(pp['native_compile_s'], 1)} / {_f(statistics.median(bc) if bc else None, 1)}"))
    widths = [max(len(str(r[i])) for r in rows) for i in range(len(rows[0]))]
    line = lambda r: "| " + " | ".join(str(x).ljust(w) for x, w in zip(r, widths)) + " |"  # noqa: E731
    out = [line(rows[0]), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out += [line(r) for r in rows[1:]]
    return "\n".join(out)


# ------------------------------------------------------------------------------- figure


def plot(res: dict, path: pathlib.Path) -> None:
    from nmrl.analysis.plots import plt, save

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    env = res.get("env")
    if env and "mjx" in env:
        for key, label, st in (("1dev_single", "MJX, 1 CPU device", "C0o-"),
                               ("2dev_shard_map", "MJX, 2 CPU devices (shard_map)", "C1s-")):
            r = env["mjx"].get(key, {}).get("results", [])
            if r:
                ax1.plot([x["batch"] for x in r], [x["physics_steps_per_s"] for x in r], st, label=label)
        for nt, st in zip(sorted({r["nthread"] for r in env["c"]}), ("C2^--", "C3v--", "C4d--")):
            r = [x for x in env["c"] if x["nthread"] == nt]
            ax1.plot([x["batch"] for x in r], [x["physics_steps_per_s"] for x in r], st,
                     label=f"MuJoCo C rollout, {nt} thread{'s' if nt > 1 else ''}")
    ax1.set_ylabel("physics steps / s (timestep 0.005 s)")
    ax1.set_title("environment only", fontsize=9)
    lr = res.get("learning")
    if lr and "results" in lr:
        r = lr["results"]
        ax2.plot([x["batch"] for x in r], [x["train"]["control_steps_per_s"] for x in r], "C0o-",
                 label="training chunk (learning), 1 device")
        ax2.plot([x["batch"] for x in r], [x["env"]["control_steps_per_s"] for x in r], "C0o:",
                 mfc="none", label="env-only scan, same batch")
    sw = res.get("sweep")
    if sw and "worker" in sw:
        w = sw["worker"]
        for key, style, label in (("new", "C2D", "sweep (learning), points over cores, one at a time"),
                                  ("single_vmap", "C2d", "sweep (learning), one vmap on one device")):
            r = w[key]
            ax2.plot([w["points"] * r["num_envs_per_point"]], [r["control_steps_per_s"]], style, label=label)
        ax2.axhline(sw["mujoco_c"]["control_steps_per_s"], color="C3", ls="--", lw=0.8,
                    label=f"MuJoCo C rollout, {sw['mujoco_c']['nthreads']} threads (no learning)")
    sc = res.get("scaling")
    if sc and "modes" in (sc.get("two_device_process") or {}):
        m = sc["two_device_process"]["modes"]
        n = sc["config"]["points"] * sc["config"]["num_envs_per_point"]
        ax2.plot([n], [m["2dev"]["control_steps_per_s"]], "C1s", label="2 points, 2 devices (shard_map)")
        ax2.plot([n], [m["1dev"]["control_steps_per_s"]], "C1s", mfc="none", label="2 points, 1 device")
    ax2.set_ylabel("control steps / s (all environments)")
    ax2.set_title("training (paper network sizes) vs env only", fontsize=9)
    for ax in (ax1, ax2):
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("batch size (environments, all points)")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    m = res.get("machine") or {}
    la = m.get("load_avg_at_start") or [float("nan")]
    fig.suptitle(f"nmrl throughput{' (quick)' if res['meta']['quick'] else ''}: {m.get('cpu', '')}, "
                 f"{m.get('cpu_count')} cores, load avg {la[0]:.1f} at start; jax {m.get('jax')}, "
                 f"mujoco {m.get('mujoco')}", fontsize=8)
    fig.tight_layout()
    save(fig, path, dpi=120)
