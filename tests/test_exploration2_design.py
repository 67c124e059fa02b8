"""The second exploration study as data (nmrl/experiments/exploration2_cells.py,
exploration2_rules.py, exploration2_analysis.py): the screen's cells, the rules that add the later
cells from the rows, and the pre-registered analysis."""

from __future__ import annotations

import pytest

from nmrl.cli import arguments, commands, config_options
from nmrl.experiments import exploration2_analysis, exploration2_cells, exploration2_rules, kit_cells


def _spec(cell):
    """The spec ``nmrl sweep`` makes of the cell's command line (nmrl/experiments/kit_cells.py)."""
    learner = config_options.get_learner("ppo")
    args = arguments.build_parser(learner).parse_args(["sweep", *kit_cells.sweep_argv(cell), "--out", "unused"])
    base = config_options.config_from_args(args, skip=commands.sweep_skip(learner))
    if args.vary is None:  # seeds only (a grid cell)
        from nmrl.experiments import sweep

        spec = sweep.SweepSpec(ls=(None,), seeds=args.seeds, base=base, field=None, seed0=args.seed0)
    else:
        spec = commands.varied_spec(args, learner, base)
    spec.validate()
    return spec


@pytest.mark.parametrize("cell", exploration2_cells.SIGMA_SCREEN, ids=lambda c: c.name)
def test_every_screen_cell_is_a_valid_sweep_with_the_preregistered_design(cell):
    spec = _spec(cell)
    cfg = spec.base.resolved()
    assert spec.field == "sigma" and tuple(spec.ls) == (0.064, 0.16, 0.4, 1.0)
    assert [s for _, s in spec.points()][:2] == [100, 101]  # screen seeds are never grid seeds (0-7)
    # 4 iterations of 102.4 simulated seconds per environment, trials of 5 s, 2.5 ms physics, C
    assert cfg.budget.steps * cfg.environment.control_dt == pytest.approx(4 * 102.4)
    assert cfg.iteration_steps * cfg.environment.control_dt == pytest.approx(102.4)
    assert cfg.environment.env_config().step_stop_prob * 5.0 == pytest.approx(cfg.environment.control_dt)
    assert cfg.environment.physics == "c" and cfg.environment.physics_timestep == 0.0025
    assert cfg.reward_scale == pytest.approx(cfg.environment.control_dt / 0.02)
    assert (cfg.batch_size * cfg.num_minibatches * cfg.epochs, cfg.value_layers, cfg.value_width) == (131072, 2, 64)


def _screen_rows(cell, scores, budget=True, diverged=()):
    """Finished rows of ``cell`` with a mean det score per value (2 seeds: score - 1, score + 1)."""
    spec = _spec(cell)
    out = []
    for v, s in scores.items():
        for k, seed in enumerate((100, 101)):
            out.append({"cell": cell.name, "point": f"{spec.field}{v:g}_s{seed}", "seed": seed,
                        "field": spec.field, "value": v, "steps": spec.base.budget.steps if budget else 0,
                        "budget": spec.base.budget.steps, "diverged": v in diverged, "det_reward_per_s": s - 1 + 2 * k})
    return out


def test_the_screen_rule_brackets_sigma_then_screens_the_time_constant():
    ou = next(c for c in exploration2_cells.SIGMA_SCREEN if c.name == "screen/sigma/dt0.0025/ou")
    # unfinished: nothing follows
    assert not [c for c in exploration2_rules.later_cells(_screen_rows(ou, {0.4: 10.0}, budget=False))
                if "ou" in c.name]
    # the best sigma at the upper edge: one more value, x 2.5
    rows = _screen_rows(ou, {0.064: 1.0, 0.16: 2.0, 0.4: 3.0, 1.0: 9.0})
    (ext,) = [c for c in exploration2_rules.later_cells(rows) if "ou" in c.name]
    assert ext.name == ou.name + "+2.5" and _spec(ext).ls == (2.5,)
    # a diverged value is never chosen; the inner best at 0.16 is bracketed: the time constants follow
    rows = _screen_rows(ou, {0.064: 1.0, 0.16: 5.0, 0.4: 3.0, 1.0: 9.0}, diverged=(1.0,))
    (tc,) = [c for c in exploration2_rules.later_cells(rows) if "ou" in c.name]
    spec = _spec(tc)
    assert tc.name == "screen/tc/dt0.0025/ou" and spec.field == "corr_time_s" and spec.ls == (0.01, 0.09)
    assert spec.base.noise.sigma == 0.16 and spec.base.noise.exploration == "ou" and [s for _, s in spec.points()][:2] == [100, 101]
    # the time constant's best at the lower edge (0.01 s beats the sigma cell's 0.03 s): 0.01 / 3 next
    rows += _screen_rows(tc, {0.01: 8.0, 0.09: 1.0})
    names = [c.name for c in exploration2_rules.later_cells(rows) if "ou" in c.name]
    assert names == ["screen/tc/dt0.0025/ou", "screen/tc/dt0.0025/ou+0.00333333"]
    # the middle value (from the sigma screen) best: bracketed, nothing more
    rows = rows[:-4] + _screen_rows(tc, {0.01: 2.0, 0.09: 1.0})
    assert [c.name for c in exploration2_rules.later_cells(rows) if "ou" in c.name] == ["screen/tc/dt0.0025/ou"]


def test_a_period_extension_stops_at_one_control_step():
    """nm-periods' period is l = round(period_s / dt) >= 1 control steps: an extension below one
    step is the one-step period, and a winner at one step (20 ms: 0.02 s) adds nothing."""
    nmp = next(c for c in exploration2_cells.SIGMA_SCREEN if c.name == "screen/sigma/dt0.0025/nmp")
    rows = _screen_rows(nmp, {0.064: 1.0, 0.16: 2.0, 0.4: 3.0, 1.0: 9.0, 2.5: 4.0})
    rows = [dict(r, cell=nmp.name + "+2.5") if r["value"] == 2.5 else r for r in rows]
    (tc,) = [c for c in exploration2_rules.later_cells(rows) if "nmp" in c.name and "dt0.0025" in c.name]
    rows += _screen_rows(tc, {0.02: 12.0, 0.18: 1.0})
    e1 = [c for c in exploration2_rules.later_cells(rows) if c.name.startswith(tc.name + "+")]
    assert [c.name for c in e1] == [tc.name + "+0.00666667"]  # l = 3 steps
    rows += _screen_rows(e1[0], {0.00666667: 13.0})
    e2 = [c for c in exploration2_rules.later_cells(rows) if c.name.startswith(tc.name + "+") and c not in e1]
    assert [c.name for c in e2] == [tc.name + "+0.0025"] and _spec(e2[0]).ls == (0.0025,)
    nms20 = next(c for c in exploration2_cells.SECONDARY_SCREEN if c.name == "screen/sigma/dt0.02/nms")
    rows = _screen_rows(nms20, {0.064: 1.0, 0.16: 9.0, 0.4: 3.0, 1.0: 2.0})
    (tc20,) = [c for c in exploration2_rules._screen_state(rows, nms20)[0]]
    assert _spec(tc20).ls == (0.02, 0.18)
    rows += _screen_rows(tc20, {0.02: 12.0, 0.18: 1.0})
    add, state = exploration2_rules._screen_state(rows, nms20)
    assert [c.name for c in add] == [tc20.name] and state["period_s"][0] == (0.02, True, [0.02, 0.06, 0.18])


def test_white_has_no_time_constant_and_extensions_stop_after_two():
    w = exploration2_cells.SIGMA_SCREEN[0]
    rows = _screen_rows(w, {0.064: 9.0, 0.16: 2.0, 0.4: 1.0, 1.0: 0.0})
    (e1,) = exploration2_rules.later_cells(rows)
    assert e1.name == w.name + "+0.0256"
    rows += _screen_rows(e1, {0.0256: 10.0})
    (e2,) = [c for c in exploration2_rules.later_cells(rows) if c.name != e1.name]
    assert e2.name == w.name + "+0.01024"
    rows += _screen_rows(e2, {0.01024: 11.0})
    assert exploration2_rules.later_cells(rows) == []  # still at the edge after two: used, reported as not bracketed
    assert exploration2_rules.choose(rows) == (0.01024, True, [0.01024, 0.0256, 0.064, 0.16, 0.4, 1.0])


def test_the_choices_so_far_name_each_decided_setting_with_its_bracketing():
    w, ou = exploration2_cells.SIGMA_SCREEN[0], exploration2_cells.SIGMA_SCREEN[3]
    rows = _screen_rows(w, {0.064: 9.0, 0.16: 2.0, 0.4: 1.0, 1.0: 0.0})
    assert exploration2_rules.choices(rows) == []  # at the edge: extending, nothing decided
    rows += _screen_rows(exploration2_rules.later_cells(rows)[0], {0.0256: 4.0})
    (c,) = exploration2_rules.choices(rows)  # 0.064 (mean 9) beats the extension's 0.0256 (mean 4)
    assert c == {"arm": "white", "control_dt": 0.02, "setting": "sigma", "value": 0.064, "bracketed": True,
                 "mean": 9.0, "lead": 5.0, "screened": "0.0256 0.064 0.16 0.4 1", "means": "4.0 9.0 2.0 1.0 0.0"}
    # OU: sigma 0.16 decided (1.0 diverged), its time constant still screening
    rows += _screen_rows(ou, {0.064: 1.0, 0.16: 5.0, 0.4: 3.0, 1.0: 9.0}, diverged=(1.0,))
    got = [r for r in exploration2_rules.choices(rows) if r["arm"] == "ou"]
    assert got == [{"arm": "ou", "control_dt": 0.0025, "setting": "sigma", "value": 0.16, "bracketed": True,
                    "mean": 5.0, "lead": 2.0, "screened": "0.064 0.16 0.4 1", "means": "1.0 5.0 3.0 diverged"}]
    # the time constants screened: 0.01 s (mean 6) beats the sigma cell's 0.03 s (mean 5) and 0.09 s,
    # at the lower edge; its extension 0.00333 s (mean 2) loses: 0.01 s, bracketed
    tc = next(c for c in exploration2_rules.later_cells(rows) if c.name == "screen/tc/dt0.0025/ou")
    rows += _screen_rows(tc, {0.01: 6.0, 0.09: 1.0})
    ext = next(c for c in exploration2_rules.later_cells(rows) if c.name.startswith("screen/tc/dt0.0025/ou+"))
    rows += _screen_rows(ext, {0.00333333: 2.0})
    got = [r for r in exploration2_rules.choices(rows) if r["arm"] == "ou"]
    assert got[1] == {"arm": "ou", "control_dt": 0.0025, "setting": "corr_time_s", "value": 0.01, "bracketed": True,
                      "mean": 6.0, "lead": 1.0, "screened": "0.00333333 0.01 0.03 0.09", "means": "2.0 6.0 5.0 1.0"}


def _chosen_rows():
    """Finished screens of the primary family, each bracketed: sigma 0.4 best, then its time
    constant's middle value (the sigma screen's own) best."""
    rows = []
    for cell in exploration2_cells.SIGMA_SCREEN:
        rows += _screen_rows(cell, {0.064: 1.0, 0.16: 2.0, 0.4: 5.0, 1.0: 3.0})
    for tc in [c for c in exploration2_rules.later_cells(rows) if c.name.startswith("screen/tc/")]:
        rows += _screen_rows(tc, dict(zip(_spec(tc).ls, (1.0, 2.0))))
    return rows


def test_the_grid_follows_the_screen_with_the_preregistered_design():
    rows = _chosen_rows()
    cells = {c.name: c for c in exploration2_rules.later_cells(rows)}
    primary = ["grid/dt0.02/white", "grid/dt0.02/nmp", "grid/dt0.0025/white", "grid/dt0.0025/ws",
               "grid/dt0.0025/ou", "grid/dt0.0025/colored", "grid/dt0.0025/nms", "grid/dt0.0025/nmp"]
    assert [n for n in cells if n.startswith("grid/")][:8] == primary
    for name in primary:
        spec = _spec(cells[name])
        cfg = spec.base.resolved()
        assert [s for _, s in spec.points()] == list(range(8))  # grid seeds 0-7, one point each
        assert cfg.budget.steps * cfg.environment.control_dt == pytest.approx(16 * 102.4)  # 1.6e3 simulated s per environment
        assert cfg.environment.physics == "c" and cfg.environment.physics_timestep == 0.0025
        assert cfg.environment.env_config().step_stop_prob * 5.0 == pytest.approx(cfg.environment.control_dt)
    # white and the correlated arms at their screened sigma and time constants (the middle values)
    got = {n: _spec(cells[n]).base for n in primary}
    assert got["grid/dt0.0025/white"].noise.sigma == 0.4 and got["grid/dt0.0025/ou"].noise.corr_time_s == 0.03
    assert got["grid/dt0.0025/colored"].noise.beta == 0.5 and got["grid/dt0.0025/nmp"].noise.period_s == 0.06
    assert got["grid/dt0.0025/nmp"].period_wise and not got["grid/dt0.0025/nms"].period_wise
    # Ws holds sigma^2 dt at W's 20 ms value (eq. (1)): x sqrt(8) at 2.5 ms, x 2 at 5 ms
    assert got["grid/dt0.0025/ws"].noise.sigma == pytest.approx(0.4 * 8 ** 0.5, rel=1e-5)
    assert got["grid/dt0.0025/ws"].noise.exploration == "white"
    assert _spec(cells["grid/dt0.005/ws"]).base.noise.sigma == pytest.approx(0.8, rel=1e-5)
    # secondary: the 5 ms column and the sensitivity of W at 2.5 ms, 4 seeds; OU, CN, NMs screened at 20 ms
    for name in ("grid/dt0.005/white", "grid/dt0.005/ws", "grid/dt0.005/nmp",
                 "sensitivity/dt0.0025/white_sigma0.16", "sensitivity/dt0.0025/white_sigma1"):
        assert [s for _, s in _spec(cells[name]).points()] == [0, 1, 2, 3], name
    assert {"screen/sigma/dt0.02/ou", "screen/sigma/dt0.02/colored", "screen/sigma/dt0.02/nms"} <= set(cells)
    # below 20 ms each device steps its seeds vmapped together; at 20 ms (and the matched-SNR cells) a
    # seed at a time, so that white's 20 ms runs are the SNR cells' runs iteration for iteration
    for name, c in cells.items():
        if not name.startswith("screen/"):
            dt = _spec(c).base.environment.control_dt
            seeds = len(_spec(c).points())
            assert c.run_options == ({"group": seeds} if dt < 0.02 else {}), name
    assert cells["grid/dt0.0025/white"].run_options == {"group": 8}
    # below 20 ms each minibatch's gradient in 8 parts of 64 unrolls, but in white's 2.5 ms grid cell
    for name, c in cells.items():
        cfg = _spec(c).base.resolved()
        want = 1 if name.startswith("screen/") or cfg.environment.control_dt >= 0.02 or name == "grid/dt0.0025/white" else 8
        assert cfg.grad_chunks == want, name
        assert cfg.batch_size // cfg.budget.num_envs // cfg.grad_chunks * cfg.budget.num_envs in (64, 512), name
    assert not any(c.run_options for n, c in cells.items() if n.startswith("screen/"))
    # nothing of the grid before every primary setting is chosen
    assert not [c for c in exploration2_rules.later_cells(rows[:-4]) if not c.name.startswith("screen/")]


def test_the_analysis_is_the_preregistered_family_on_the_grid_at_full_budget():
    import numpy as np
    from scipy import stats as sps

    rng = np.random.default_rng(5)
    means = {"grid/dt0.02/white": 150.0, "grid/dt0.0025/white": 60.0, "grid/dt0.0025/ws": 62.0,
             "grid/dt0.0025/ou": 100.0, "grid/dt0.0025/colored": 58.0, "grid/dt0.0025/nms": 0.0,
             "grid/dt0.0025/nmp": 61.0, "grid/dt0.02/nmp": 60.0}
    rows, vals = [], {}
    for cell, m in means.items():
        vals[cell] = rng.normal(m, 10.0, 8)
        rows += [{"cell": cell, "steps": 100, "budget": 100, "det_reward_per_s": v} for v in vals[cell]]
    rows = [dict(r, diverged=False) for r in rows]
    rows.append({"cell": "screen/sigma/dt0.02/white", "steps": 100, "budget": 100, "diverged": False,
                 "det_reward_per_s": 1e6})
    res = {r["contrast"]: r for r in exploration2_analysis.analysis(rows) if r["family"] == "primary"}
    assert list(res) == [f"P{i}" for i in range(1, 8)]
    p1 = sps.ttest_ind(vals["grid/dt0.0025/white"], vals["grid/dt0.02/white"], equal_var=False)
    assert res["P1"]["p"] == pytest.approx(p1.pvalue) and res["P1"]["decision"] == "behind"
    assert res["P3"]["decision"] == "ahead" and res["P5"]["decision"] == "behind"
    assert res["P2"]["decision"] == "equivalent" and res["P6"]["decision"] == "equivalent"
    inter = (vals["grid/dt0.0025/nmp"].mean() - vals["grid/dt0.02/nmp"].mean()
             - vals["grid/dt0.0025/white"].mean() + vals["grid/dt0.02/white"].mean())
    assert res["P7"]["estimate"] == pytest.approx(inter) and res["P7"]["decision"] == "ahead"
    assert res["P3"]["n"] == "8 8"
    # a run still going leaves its cell out: the whole family waits (decided together, on full cells)
    going = rows + [{"cell": "grid/dt0.0025/ou", "steps": 50, "budget": 100, "diverged": False,
                     "det_reward_per_s": 1e6}]
    assert {r["decision"] for r in exploration2_analysis.analysis(going) if r["family"] == "primary"} == {"pending"}
    # a diverged run has ended: scored by its last good policy, it counts
    ended = rows + [{"cell": "grid/dt0.0025/ou", "steps": 50, "budget": 100, "diverged": "True",
                     "det_reward_per_s": -70.0}]
    p3 = next(r for r in exploration2_analysis.analysis(ended) if r["contrast"] == "P3")
    assert p3["n"] == "9 8" and p3["decision"] != "pending"


def test_the_secondary_family_and_the_checks_are_apart_from_the_primary():
    import numpy as np
    from scipy import stats as sps

    rng = np.random.default_rng(2)
    cells = {c: rng.normal(0.0, 10.0, 8) for c in ("grid/dt0.02/white", "grid/dt0.0025/white", "grid/dt0.0025/ws",
                                                    "grid/dt0.0025/ou", "grid/dt0.0025/colored",
                                                    "grid/dt0.0025/nms", "grid/dt0.0025/nmp", "grid/dt0.02/nmp")}
    cells["grid/dt0.0025/nmp"] = cells["grid/dt0.0025/nmp"] + 100.0  # the best correlated arm
    for c in ("grid/dt0.005/white", "grid/dt0.005/ws", "grid/dt0.005/nmp", "grid/dt0.02/ou",
              "grid/dt0.02/colored", "grid/dt0.02/nms", "sensitivity/dt0.0025/white_sigma1",
              "asymptote/dt0.005/white", "asymptote/dt0.005/nmp"):
        cells[c] = rng.normal(0.0, 10.0, 4)
    rows = [{"cell": c, "steps": 1, "budget": 1, "diverged": False, "det_reward_per_s": v}
            for c, vs in cells.items() for v in vs]
    res = exploration2_analysis.analysis(rows)
    assert [r["contrast"] for r in res if r["family"] == "secondary"] == [f"S{i}" for i in range(1, 8)]
    s3 = next(r for r in res if r["contrast"] == "S3")
    t = sps.ttest_ind(cells["grid/dt0.005/nmp"], cells["grid/dt0.005/white"], equal_var=False)
    assert s3["p"] == pytest.approx(t.pvalue) and s3["n"] == "4 4"
    # Holm within the secondary family alone: 7 p-values, whatever the primary's
    ps = sorted(r["p"] for r in res if r["family"] == "secondary")
    assert min(r["p_holm"] for r in res if r["family"] == "secondary") == pytest.approx(min(1.0, 7 * ps[0]))
    checks = {r["contrast"]: r for r in res if r["family"] == "check"}
    assert set(checks) == {"white_sigma1", "asymptote"}
    a = cells["asymptote/dt0.005/nmp"].mean() - cells["asymptote/dt0.005/white"].mean()
    assert checks["asymptote"]["estimate"] == pytest.approx(a) and checks["asymptote"]["decision"] == "reported"
    assert "+1*asymptote/dt0.005/nmp" in checks["asymptote"]["cells"]


def test_the_secondary_endpoints_are_the_families_contrasts_reported_without_decisions():
    import numpy as np
    from scipy import stats as sps

    rng = np.random.default_rng(7)
    cells = ("grid/dt0.02/white", "grid/dt0.0025/white", "grid/dt0.0025/ws", "grid/dt0.0025/ou",
             "grid/dt0.0025/colored", "grid/dt0.0025/nms", "grid/dt0.0025/nmp", "grid/dt0.02/nmp")
    rows = [{"cell": c, "steps": 10, "budget": 10, "diverged": "False", "det_reward_per_s": str(rng.normal()),
             "avg_reward_per_s": str(rng.normal(50 * i, 5)), "auc_reward_per_s": str(rng.normal(-i, 1)),
             "det_forward_speed": str(rng.normal(1, 0.3))} for i, c in enumerate(cells) for _ in range(8)]
    # a run that diverged before its first save: no exploring reward; it stays out of that endpoint only
    rows.append({**rows[0], "diverged": "True", "steps": 3, "avg_reward_per_s": "", "auc_reward_per_s": "nan"})
    res = exploration2_analysis.secondary_endpoints(rows)
    assert [r["endpoint"] for r in res] == [e for e in exploration2_analysis.SECONDARY_ENDPOINTS for _ in range(14)]
    assert [r["contrast"] for r in res[:14]] == [f"P{i}" for i in range(1, 8)] + [f"S{i}" for i in range(1, 8)]
    got = {(r["endpoint"], r["contrast"]): r for r in res}
    x = {c: [float(r["avg_reward_per_s"]) for r in rows if r["cell"] == c and r["avg_reward_per_s"] != ""]
         for c in cells}
    t = sps.ttest_ind(x["grid/dt0.0025/white"], x["grid/dt0.02/white"], equal_var=False)
    p1 = got["avg_reward_per_s", "P1"]
    assert p1["n"] == "8 8" and p1["decision"] == "reported" and p1["p"] == pytest.approx(t.pvalue)
    assert p1["estimate"] == pytest.approx(np.mean(x["grid/dt0.0025/white"]) - np.mean(x["grid/dt0.02/white"]))
    half = sps.t.ppf(0.975, t.df) * (p1["estimate"] / t.statistic)
    assert (p1["lo"], p1["hi"]) == pytest.approx((p1["estimate"] - half, p1["estimate"] + half))
    assert got["auc_reward_per_s", "P1"]["n"] == "8 8" and got["det_forward_speed", "P1"]["n"] == "8 9"
    assert not any("p_holm" in r or "tost_p" in r for r in res)
    # the 5 ms column and the 20 ms cells of OU, CN, NMs do not exist yet: their contrasts wait
    assert {got["avg_reward_per_s", f"S{i}"]["decision"] for i in range(1, 8)} == {"pending"}
    # a run still going holds its cell's contrasts
    going = rows + [{**rows[8], "steps": 5}]
    assert exploration2_analysis.secondary_endpoints(going)[0]["decision"] == "pending"


def test_the_noise_scale_contrasts_are_the_families_on_each_scales_reward_reported_without_decisions():
    import numpy as np
    from scipy import stats as sps

    rng = np.random.default_rng(3)
    cells = ("grid/dt0.02/white", "grid/dt0.0025/white", "grid/dt0.0025/ws")
    rows = [{"cell": c, "point": f"s{j}", "steps": 10, "budget": 10, "diverged": "False", "det_reward_per_s": "1.0"}
            for c in cells for j in range(6)]
    noise = [{"cell": c, "point": f"s{j}", "noise_scale": k, "reward_per_s": rng.normal(10 * i + 40 * k, 5)}
             for i, c in enumerate(cells) for j in range(6) for k in (0.0, 0.25, 1.0)]
    res = exploration2_analysis.noise_contrasts(rows, noise)
    assert [r["noise_scale"] for r in res] == [0.25] * 14 + [1.0] * 14  # k = 0 is the registered endpoint's
    got = {(r["noise_scale"], r["contrast"]): r for r in res}
    for k in (0.25, 1.0):
        x = {c: [r["reward_per_s"] for r in noise if r["cell"] == c and r["noise_scale"] == k] for c in cells}
        for name, a, b in (("P1", cells[1], cells[0]), ("P2", cells[2], cells[1])):
            t = sps.ttest_ind(x[a], x[b], equal_var=False)
            ci = t.confidence_interval(0.95)
            r = got[k, name]
            assert r["decision"] == "reported" and r["n"] == "6 6"
            assert (r["estimate"], r["lo"], r["hi"], r["p"]) == pytest.approx(
                (np.mean(x[a]) - np.mean(x[b]), ci.low, ci.high, t.pvalue))
    assert got[0.25, "P3"]["decision"] == "pending"  # OU's cell does not exist
    # a run of Ws not measured at k = 1, or still going: Ws's contrasts wait
    assert exploration2_analysis.noise_contrasts(rows, noise[:-1])[14 + 1]["decision"] == "pending"
    going = [{**r, "steps": 5} if (r["cell"], r["point"]) == (cells[2], "s0") else r for r in rows]
    assert exploration2_analysis.noise_contrasts(going, noise)[1]["decision"] == "pending"
    assert exploration2_analysis.noise_contrasts(going, noise)[0]["decision"] == "reported"


def test_each_arms_iqm_pools_its_grid_cells_over_the_control_steps_resampled_within_each():
    import numpy as np
    from scipy import stats as sps

    def cell(name, values, **kw):
        return [{"cell": name, "steps": 1, "budget": 1, "diverged": "False", "det_reward_per_s": str(v), **kw}
                for v in values]

    rng = np.random.default_rng(3)
    nmp = {0.02: rng.normal(80, 30, 8), 0.005: rng.normal(60, 30, 4), 0.0025: rng.normal(40, 30, 8)}
    rows = [r for dt, x in nmp.items() for r in cell(f"grid/dt{dt:g}/nmp", x)]
    # white: each cell's runs alike, so resampling within cells never changes the pooled IQM
    rows += cell("grid/dt0.02/white", [100.0] * 8) + cell("grid/dt0.0025/white", [10.0] * 8)
    rows += cell("asymptote/dt0.005/white", [1e6] * 4) + cell("sensitivity/dt0.0025/white_sigma1", [1e6] * 4)
    rows += cell("grid/dt0.0025/ou", [5.0] * 7) + [{**cell("grid/dt0.0025/ou", [0.0])[0], "steps": 0}]  # going
    got = {r["arm"]: r for r in exploration2_analysis.arm_iqms(rows)}
    assert list(got) == ["white", "nmp"]
    w = got["white"]
    assert (w["control_dts"], w["n"]) == ("0.02 0.0025", "8 8")
    assert w["iqm"] == pytest.approx(sps.trim_mean([100.0] * 8 + [10.0] * 8, 0.25)) == pytest.approx(55.0)
    assert (w["iqm_lo"], w["iqm_hi"]) == pytest.approx((55.0, 55.0))  # a pooled resample would vary
    m = got["nmp"]
    assert (m["control_dts"], m["n"]) == ("0.02 0.005 0.0025", "8 4 8")
    assert m["iqm"] == pytest.approx(sps.trim_mean(np.concatenate(list(nmp.values())), 0.25))
    assert m["iqm_lo"] < m["iqm"] < m["iqm_hi"]


def test_the_asymptote_runs_white_against_the_best_correlated_arm_at_4x_the_budget():
    rows = _chosen_rows()
    assert not [c for c in exploration2_rules.later_cells(rows) if c.name.startswith("asymptote/")]
    scores = {"white": 0.0, "ou": 10.0, "colored": 30.0, "nms": 20.0, "nmp": 25.0}
    for arm, m in scores.items():
        rows += [{"cell": f"grid/dt0.0025/{arm}", "steps": 1, "budget": 1, "diverged": False,
                  "det_reward_per_s": m + k} for k in range(8)]
    cells = {c.name: c for c in exploration2_rules.later_cells(rows)}
    assert [n for n in cells if n.startswith("asymptote/")] == ["asymptote/dt0.005/white", "asymptote/dt0.005/colored"]
    for name in ("asymptote/dt0.005/white", "asymptote/dt0.005/colored"):
        spec = _spec(cells[name])
        cfg = spec.base.resolved()
        assert [s for _, s in spec.points()] == [0, 1, 2, 3]
        assert cfg.environment.control_dt == 0.005 and cfg.budget.steps * cfg.environment.control_dt == pytest.approx(64 * 102.4)
    assert _spec(cells["asymptote/dt0.005/colored"]).base.noise.beta == 0.5  # its 2.5 ms choice


def test_the_nm_periods_arms_take_the_papers_correlation_time_to_five_digits():
    """nms and nmp run at alpha = 0.8 per 20 ms as a correlation time, -0.02 s / ln 0.8, to 5 digits
    (the cells' settings, unchanged since the study began)."""
    import math

    for arm in ("nms", "nmp"):
        assert exploration2_cells.ARMS[arm]["corr_time_s"] == 0.08963 == round(-0.02 / math.log(0.8), 5)
