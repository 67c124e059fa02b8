"""The exploration x control-step study's numbers: the screen's choice, one row per run, the answers.

Everything here reads run directories (``metrics.jsonl``, ``eval/eval.json``) and rows; nothing
trains. The study itself is nmrl/experiments/exploration_study.py, its page docs/exploration-study.md.

* The screen's rule (:func:`choose`): per process, the setting whose seeds have the highest mean
  *score*, the average reward per control step over the second half of the screen run's chunks
  (one chunk = one PPO iteration); a diverged run is never chosen (its setting scores -inf).
* A run's row (:func:`run_row`): ``avg_reward`` is the exploring policy's average reward per
  control step over the last tenth of its chunks (nmrl.analysis.stats.final_avg; at the study's 16
  iterations: the last one), ``det_reward`` the deterministic policy's over a 10 s evaluation
  (``nmrl eval``'s ``deterministic.avg_reward``). The rewards (8)-(14) are rates, so the average
  reward per second is ``mean(r_t) / 0.02 s`` at every control step (nmrl/experiments/timescale.py):
  ``avg_reward_per_s``, ``det_reward_per_s``. ``auc_reward_per_s`` is the mean of the exploring
  policy's reward per second over every iteration of the run (the area under its learning curve
  per simulated second): how fast it learned, less noisy than one iteration while the curves rise.
* The answers (:func:`answers`): per (control step, process) the mean and 95% t-interval over seeds;
  differences of two cells with Welch's interval (nmrl.analysis.stats).
"""

from __future__ import annotations

import json
import math
import pathlib
from typing import Iterable, Sequence

import numpy as np

from nmrl.analysis import gait_pictures, stats
from nmrl.runs import store

#: the control step the paper's rewards are per-step values of (reward per second = mean r_t / DELTA_0)
DELTA_0 = 0.02
RESULT_COLUMNS = ("learner", "exploration", "setting", "control_dt", "seed", "control_steps", "simulated_s",
                  "iterations", "avg_reward", "avg_reward_per_s", "auc_reward_per_s", "det_reward", "det_reward_per_s",
                  "forward_speed", "det_forward_speed", "diverged")
SCREEN_COLUMNS = ("exploration", "field", "value", "seed", "iterations", "score", "diverged", "chosen")


def score(rows: Sequence[dict]) -> float:
    """The screen's score of one run: mean ``avg_reward`` over the second half of its chunks
    (the later half when the count is odd); -inf for a diverged run or one without chunks."""
    if not rows or any(store.is_diverged(r) for r in rows):
        return -math.inf
    half = rows[len(rows) // 2:]
    return float(np.mean([r["avg_reward"] for r in half]))


def choose(screen_rows: Sequence[dict]) -> dict[str, tuple[str, float]]:
    """``{process: (field, value)}``: per process, the value whose runs have the highest mean
    score (ties: the first value listed); a value with a diverged run scores -inf."""
    by: dict[str, dict[float, list[float]]] = {}
    fields: dict[str, str] = {}
    for r in screen_rows:
        by.setdefault(r["exploration"], {}).setdefault(float(r["value"]), []).append(float(r["score"]))
        fields[r["exploration"]] = r["field"]
    out = {}
    for proc, vals in by.items():
        best = max(vals, key=lambda v: (np.mean(vals[v]) if all(math.isfinite(s) for s in vals[v]) else -math.inf))
        out[proc] = (fields[proc], best)
    return out


def eval_summary(point: pathlib.Path) -> dict | None:
    """The deterministic policy's part of a point's ``eval/eval.json`` (None if not evaluated)."""
    f = point / "eval" / "eval.json"
    if not f.is_file():
        return None
    d = json.loads(f.read_text())
    return {"step": d.get("step"), **d["deterministic"]}


def det_reward(ev: dict) -> float:
    """The deterministic policy's average reward per control step in an eval: ``avg_reward`` of the
    paper robot's rollout, or a task's (nmrl/analysis/task_eval.py) returns summed over its
    episodes' steps."""
    if "avg_reward" in ev:
        return ev["avg_reward"]
    return float(np.sum(ev["return"]["each"]) / max(1, int(np.sum(ev["length"]))))


def run_row(point: pathlib.Path, *, exploration: str, setting: str, control_dt: float, seed: int,
            num_envs: int, iteration_steps: int, step_s: float = DELTA_0) -> dict | None:
    """One row of results.csv for the run in ``point`` (None if it has no metrics). ``step_s``: the
    seconds a per-step reward is the rate over (:data:`DELTA_0` on the paper's robot; a Gymnasium
    task's rewards are integrated over the control step: ``control_dt``)."""
    m = store.read_metrics(point)
    if not m:
        return None
    step = int(m[-1]["step"])
    ev = eval_summary(point)
    det = det_reward(ev) if ev is not None and ev.get("step") == step else float("nan")
    det_speed = ev["forward_speed"] if ev is not None and ev.get("step") == step else float("nan")
    avg = stats.final_avg(m, "avg_reward")
    return {"learner": "ppo", "exploration": exploration, "setting": setting, "control_dt": control_dt,
            "seed": seed, "control_steps": step * num_envs, "simulated_s": step * num_envs * control_dt,
            "iterations": step // iteration_steps, "avg_reward": avg, "avg_reward_per_s": avg / step_s,
            "auc_reward_per_s": float(np.mean([r["avg_reward"] for r in m])) / step_s,
            "det_reward": det, "det_reward_per_s": det / step_s,
            "forward_speed": stats.final_avg(m, "forward_speed"), "det_forward_speed": det_speed,
            "diverged": bool(any(store.is_diverged(r) for r in m))}


def cells(rows: Iterable[dict], key: str) -> dict[tuple[float, str], np.ndarray]:
    """``{(control_dt, exploration): values of key over seeds}`` (NaN values dropped)."""
    out: dict[tuple[float, str], list[float]] = {}
    for r in rows:
        v = float(r[key])
        if math.isfinite(v):
            out.setdefault((float(r["control_dt"]), r["exploration"]), []).append(v)
    return {k: np.array(v) for k, v in out.items()}


def cell_table(rows: Sequence[dict], key: str) -> list[dict]:
    """Per (control step, process): seeds, mean and 95% t half-width of ``key``."""
    out = []
    for (dt, proc), v in sorted(cells(rows, key).items()):
        m, h = stats.mean_ci95(v) if len(v) > 1 else (float(v.mean()), float("nan"))
        out.append({"control_dt": dt, "exploration": proc, "n": len(v), "mean": m, "ci95": h})
    return out


def diff(rows: Sequence[dict], key: str, a: tuple[float, str], b: tuple[float, str]) -> dict | None:
    """Cell ``a`` minus cell ``b`` of ``key``: difference of the means and Welch's 95% half-width
    (None if either cell has fewer than 2 values)."""
    c = cells(rows, key)
    if a not in c or b not in c or len(c[a]) < 2 or len(c[b]) < 2:
        return None
    d, h = stats.diff_ci95(c[b], c[a])  # mean(a) - mean(b)
    return {"a": list(a), "b": list(b), "diff": d, "ci95": h, "significant": bool(abs(d) > h)}


def interaction(rows: Sequence[dict], key: str, a: str, b: str, fine: float, coarse: float) -> dict | None:
    """How much more process ``a`` changes from ``coarse`` to ``fine`` than process ``b`` does:
    ``(a_fine - a_coarse) - (b_fine - b_coarse)`` of ``key`` with its Welch-Satterthwaite 95%
    half-width (nmrl.analysis.stats.contrast_ci95; None if a cell has fewer than 2 values). The
    paper's thesis in one number: with ``b`` = white, a process that keeps its exploration at fine
    control steps loses less than white, so its interaction is positive."""
    c = cells(rows, key)
    need = [(fine, a), (coarse, a), (fine, b), (coarse, b)]
    if any(k not in c or len(c[k]) < 2 for k in need):
        return None
    d, h = stats.contrast_ci95([c[k] for k in need], [1.0, -1.0, -1.0, 1.0])
    return {"a": a, "b": b, "fine": fine, "coarse": coarse, "diff": d, "ci95": h,
            "significant": bool(abs(d) > h)}


def step_pairs(dts: Sequence[float]) -> list[tuple[float, float]]:
    """``(finer, coarser)`` for each control step and the next coarser one, where there are more
    than two steps (with two, the one pair is the coarsest-to-finest change itself)."""
    d = sorted(set(dts), reverse=True)
    return [(f, c) for c, f in zip(d, d[1:])] if len(d) > 2 else []


def answers(rows: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
            key: str = "avg_reward_per_s") -> dict:
    """The study's questions as numbers (docs/exploration-study.md): white's change from the
    coarsest to the finest control step; every process against white at each control step; every
    process's own change, from the coarsest to the finest step and from each step to the next finer
    one (:func:`step_pairs`), and that change against white's (:func:`interaction`); every process at
    the finest step against white at the coarsest; the best process per control step (where every
    process has runs) and its lead over the second; nm-periods against each stationary correlated
    process."""
    coarse, fine = max(dts), min(dts)
    out: dict = {"key": key, "cells": cell_table(rows, key)}
    out["white_fine_minus_coarse"] = diff(rows, key, (fine, "white"), (coarse, "white"))
    out["process_minus_white"] = [d for dt in dts for p in processes if p != "white"
                                  for d in [diff(rows, key, (dt, p), (dt, "white"))] if d]
    out["process_fine_minus_coarse"] = [d for p in processes for d in [diff(rows, key, (fine, p), (coarse, p))] if d]
    out["process_step_change"] = [d for finer, coarser in step_pairs(dts) for p in processes
                                  for d in [diff(rows, key, (finer, p), (coarser, p))] if d]
    out["process_fine_minus_white_coarse"] = [d for p in processes if p != "white"
                                              for d in [diff(rows, key, (fine, p), (coarse, "white"))] if d]
    out["change_minus_white_change"] = [d for p in processes if p != "white"
                                        for d in [interaction(rows, key, p, "white", fine, coarse)] if d]
    best, margin = {}, {}
    for dt in dts:
        have = [t for t in out["cells"] if t["control_dt"] == dt]
        if {t["exploration"] for t in have} >= set(processes):
            first, second = sorted(have, key=lambda t: -t["mean"])[:2]
            best[f"{dt:g}"] = first["exploration"]
            margin[f"{dt:g}"] = diff(rows, key, (dt, first["exploration"]), (dt, second["exploration"]))
    out["best"] = best
    out["best_margin"] = margin
    out["nm_periods_minus_stationary"] = [d for dt in dts for p in ("ou", "colored") if p in processes
                                          for d in [diff(rows, key, (dt, "nm-periods"), (dt, p))] if d]
    return out



#: the control's label in its rows' ``exploration`` column while it is compared with the grid
CONTROL = "white, more environments"
#: the measures every comparison is made for, by their results.csv column
KEYS = ("avg_reward_per_s", "det_reward_per_s", "auc_reward_per_s")


def control_answers(control: Sequence[dict], grid: Sequence[dict], coarse: float, fine: float) -> dict:
    """The samples-per-update control as numbers: `white` at the ``coarse`` control step with
    ``coarse / fine`` times the environments and the minibatch (so each Adam step sees as many
    samples as at ``fine``, in the same number of Adam steps, over that many times the simulated
    time) against `white` at ``fine`` (is the finer step's gain more than the samples per update?)
    and at ``coarse`` (do more samples per update help at the coarse step?). Per measure of
    :data:`KEYS`: the control's cell and both Welch differences (None where a side has fewer than
    2 finished runs)."""
    rows = [{**r, "exploration": CONTROL} for r in control] + [r for r in grid if r["exploration"] == "white"]
    out = {}
    for key in KEYS:
        cell = [c for c in cell_table(rows, key) if c["exploration"] == CONTROL]
        out[key] = {"cell": cell[0] if cell else None,
                    "minus_white_fine": diff(rows, key, (coarse, CONTROL), (fine, "white")),
                    "minus_white_coarse": diff(rows, key, (coarse, CONTROL), (coarse, "white"))}
    return out


def iteration_means(runs: Sequence[Sequence[dict]], step_s: float = DELTA_0) -> list[dict]:
    """Per PPO iteration (one ``metrics.jsonl`` row each) that every run of ``runs`` has reached:
    the exploring policy's average reward per second (per-step rewards over ``step_s``, as
    :func:`run_row`), mean and 95% t half-width over the runs."""
    n = min((len(m) for m in runs), default=0)
    out = []
    for i in range(n):
        m, h = stats.mean_ci95(np.array([r[i]["avg_reward"] for r in runs], float) / step_s)
        out.append({"iteration": i + 1, "mean": m, "ci95": h, "runs": len(runs)})
    return out


def finished(rows: Sequence[dict], iterations: int) -> list[dict]:
    """The rows of runs that are over: their full ``iterations``, or diverged. The answers are made
    of these only (a run half way through is not a result)."""
    return [r for r in rows if int(r["iterations"]) >= iterations or r["diverged"] is True]


def _ms(dt: float) -> str:
    """A control step in milliseconds, as the tables and words name it."""
    return f"{dt * 1000:g} ms"


def _with_others(main: dict, others: Sequence[tuple[str, dict | None]]) -> str:
    """A difference per second, then the same difference for the other measures in brackets."""
    rest = [f"{name} {_pm(x['diff'], x['ci95'])}" for name, x in others if x]
    return _pm(main["diff"], main["ci95"]) + " per s" + (f" ({'; '.join(rest)})" if rest else "")


def _pm(m: float, h: float, digits: int = 1) -> str:
    if not math.isfinite(m):
        return "–"
    return f"{m:+.{digits}f}" + (f" ± {h:.{digits}f}" if math.isfinite(h) else "")


def _d(x: dict | None) -> str:
    if x is None:
        return "–"
    return _pm(x["diff"], x["ci95"]) + (" **(significant)**" if x["significant"] else "")


def _index(a: dict) -> dict:
    """Every difference of one :func:`answers` dict by what it compares: ``(cell a, cell b)`` for
    differences of two cells, ``(process a, process b)`` for interactions."""
    out = {}
    for k in ("white_fine_minus_coarse", "process_minus_white", "process_fine_minus_coarse",
              "process_step_change", "nm_periods_minus_stationary", "process_fine_minus_white_coarse"):
        v = a.get(k)
        for x in ([v] if isinstance(v, dict) else v or []):
            out[(tuple(x["a"]), tuple(x["b"]))] = x
    for x in (a.get("best_margin") or {}).values():
        if x:
            out[(tuple(x["a"]), tuple(x["b"]))] = x
    for x in a.get("change_minus_white_change") or []:
        out[(x["a"], x["b"])] = x
    return out


def _get(ix: dict, key: tuple) -> dict | None:
    """The difference ``key`` = (a, b) from an :func:`_index`, or b - a's negated when only that
    one is there (same interval)."""
    if key in ix:
        return ix[key]
    x = ix.get(key[::-1])
    return None if x is None else {**x, "a": x["b"], "b": x["a"], "diff": -x["diff"]}


def _sign(x: dict | None, ahead: str = "significantly ahead", behind: str = "significantly behind") -> str:
    """A difference in words: significantly positive, significantly negative, or neither."""
    if x is None:
        return "not yet measured"
    if not x["significant"]:
        return "no significant difference"
    return ahead if x["diff"] > 0 else behind


def plain_answers(summary: dict, dts: Sequence[float], processes: Sequence[str]) -> list[str]:
    """The study's questions (docs/exploration-study.md) answered in words from ``summary``'s
    numbers: each answer is the exploring policy's average reward per second over the last
    iteration (Welch 95% intervals over seeds; "significant" = the interval excludes 0), with the
    same difference for the deterministic policy and for the whole run's mean in brackets. A
    question whose cells have no finished runs yet says so."""
    ix = {k: _index(summary.get(k) or {}) for k in ("answers", "answers_deterministic", "answers_auc")}
    dts = sorted(dts, reverse=True)
    fine, coarse = min(dts), max(dts)

    def num(key) -> str:
        main = _get(ix["answers"], key)
        if main is None:
            return "not yet measured"
        return _with_others(main, [("deterministic", _get(ix["answers_deterministic"], key)),
                                   ("whole run", _get(ix["answers_auc"], key))])

    def said(key, *words) -> str:
        """The difference ``key`` and its meaning in words, or "not yet measured" once."""
        x = _get(ix["answers"], key)
        return "not yet measured" if x is None else f"{num(key)}, {_sign(x, *words)}"

    cells = {(c["control_dt"], c["exploration"]): c for c in (summary.get("answers") or {}).get("cells", [])}
    out = ["## The answers in words", "",
           "Each number is a difference of mean rewards per second with its Welch 95% interval over the finished "
           "seeds: first the exploring policy over the last iteration, then in brackets the deterministic policy "
           "and the exploring policy's mean over the whole run.", ""]
    w = ((fine, "white"), (coarse, "white"))
    wd = _get(ix["answers"], w)
    out.append(f"1. **Does `white` PPO degrade from {_ms(coarse)} to {_ms(fine)}?** `white` {_ms(fine)} − {_ms(coarse)}: "
               + (f"not yet measured (`white` needs finished runs at both)." if wd is None else f"{num(w)}: " +
                                {"significantly behind": "yes, it degrades.",
                                 "significantly ahead": "no, it improves.",
                                 "no significant difference": "no significant change."}[_sign(wd)])
               + "".join(f" {_ms(f)} − {_ms(c)}: {said(((f, 'white'), (c, 'white')), 'an improvement', 'a degradation')}."
                         for f, c in step_pairs(dts)))
    out.append(f"2. **Does a correlated process remove the degradation?** Each process's own change from "
               f"{_ms(coarse)} to {_ms(fine)}, that change against `white`'s (positive: it loses less than `white`), "
               f"and the process at {_ms(fine)} against `white` at {_ms(coarse)}:")
    removers, reducers = [], []
    for p in processes:
        if p == "white":
            continue
        it = _get(ix["answers"], (p, "white"))
        vs = _get(ix["answers"], ((fine, p), (coarse, "white")))
        out.append(f"   * `{p}`: own change {num(((fine, p), (coarse, p)))}; against `white`'s "
                   f"{said((p, 'white'), 'loses significantly less than `white`', 'loses significantly more than `white`')}; "
                   f"against `white` at {_ms(coarse)} {said(((fine, p), (coarse, 'white')))}.")
        if it and it["significant"] and it["diff"] > 0:
            (removers if vs and not (vs["significant"] and vs["diff"] < 0) else reducers).append(p)
    names = lambda ps: ", ".join(f"`{p}`" for p in ps)  # noqa: E731
    if wd is None:
        out.append("   * Not yet answerable: `white` has no finished runs at both control steps.")
    elif not (wd["significant"] and wd["diff"] < 0):
        out.append("   * `white` " + ("improves significantly" if wd["significant"] else "does not change significantly")
                   + ", so there is no degradation to remove; the changes above say whether a process gains or "
                     "loses more than `white`.")
    else:
        verdict = []
        if removers:
            verdict.append(f"removed by {names(removers)} (less loss than `white`, and at {_ms(fine)} not behind "
                           f"`white` at {_ms(coarse)})")
        if reducers:
            verdict.append(f"reduced but not removed by {names(reducers)} (less loss than `white`, but at "
                           f"{_ms(fine)} significantly behind `white` at {_ms(coarse)})")
        out.append("   * " + ("; ".join(verdict).capitalize() if verdict else
                              "No process removes or reduces it (none loses significantly less than `white`)") + ".")
    out.append("3. **Which process is best at each control step?** (highest mean; its lead over the second):")
    margins = (summary.get("answers") or {}).get("best_margin") or {}
    for dt in dts:
        m = margins.get(f"{dt:g}")
        if m is None:
            out.append(f"   * {_ms(dt)}: not yet measured (every process needs finished runs).")
            continue
        a, b = m["a"][1], m["b"][1]
        out.append(f"   * {_ms(dt)}: `{a}` ({_pm(cells[(dt, a)]['mean'], cells[(dt, a)]['ci95'])} per s), ahead of "
                   f"`{b}` by {num(((dt, a), (dt, b)))}: "
                   + ("a significant lead." if m["significant"] else "not a significant lead."))
    out.append("4. **Reset or correlation?** nm-periods (correlated, reset at each period's end) against the "
               "stationary correlated processes:")
    for dt in dts:
        parts = [f"− `{q}` {said(((dt, 'nm-periods'), (dt, q)))}"
                 for q in ("ou", "colored") if q in processes]
        out.append(f"   * {_ms(dt)}: nm-periods " + "; ".join(parts) + ".")
    claims = (("colored", "CN-PPO (colored noise, β = 0.5 best, ahead of white in PPO)"),
              ("ou", "ARP (stationary autoregressive noise ahead of white, more so at high control rates)"))
    out.append("5. **Against CN-PPO and ARP:**")
    for p, claim in claims:
        if p not in processes:
            continue
        per = "; ".join(f"{_ms(dt)} {said(((dt, p), (dt, 'white')))}"
                        for dt in dts)
        out.append(f"   * {claim}: `{p}` − `white`: {per}; its lead's change from {_ms(coarse)} to {_ms(fine)}: "
                   f"{said((p, 'white'), 'grows significantly', 'shrinks significantly')}.")
    ctl = summary.get("control")
    if ctl:
        k = ctl["envs_factor"]

        def cnum(name: str) -> str:
            x = ctl["answers"]["avg_reward_per_s"][name]
            if x is None:
                return "not yet measured"
            return _with_others(x, [("deterministic", ctl["answers"]["det_reward_per_s"][name]),
                                    ("whole run", ctl["answers"]["auc_reward_per_s"][name])]) + f", {_sign(x)}"

        fine_x = ctl["answers"]["avg_reward_per_s"]["minus_white_fine"]
        auc_x = ctl["answers"]["auc_reward_per_s"]["minus_white_fine"]
        if fine_x is None:
            verdict = ""
        elif fine_x["significant"]:
            verdict = (" The finer step helps beyond the samples per update." if fine_x["diff"] < 0 else
                       f" More samples per update at {_ms(coarse)} do better than the finer step: the samples per "
                       f"update explain its gain.")
        elif auc_x is not None and auc_x["significant"] and auc_x["diff"] < 0:
            verdict = (f" Over the whole run the finer step learns significantly faster than more samples per "
                       f"update at {_ms(coarse)} do; at the last iteration the two are not distinguishable.")
        else:
            verdict = " The finer step's gain may be the samples per update."
        out.append(f"6. **Is the finer step's gain only more samples per update?** `white` at {_ms(coarse)} with "
                   f"{k}× the environments and minibatch (each Adam step on as many samples as at {_ms(fine)}, the "
                   f"same Adam steps, {k}× the simulated time): − `white` at {_ms(fine)} {cnum('minus_white_fine')}; "
                   f"− `white` at {_ms(coarse)} {cnum('minus_white_coarse')}.{verdict}")
    return out + [""]


def _columns(dts: Sequence[float]) -> tuple[str, str]:
    """A Markdown table's header cells (one per control step, coarsest first) and its rule."""
    return " | ".join(f"{dt * 1000:g} ms" for dt in dts), "|---" * (len(dts) + 1) + "|"


def _progress_lines(results: Sequence[dict], dts: Sequence[float], processes: Sequence[str]) -> list[str]:
    """Iterations done by each seed of every cell."""
    progress: dict = {}
    for r in results:
        progress.setdefault((float(r["control_dt"]), r["exploration"]), []).append(int(r["iterations"]))
    head, rule = _columns(dts)
    return ["## Progress (iterations per seed)", "", f"| process | {head} |", rule] + [
        f"| {p} | " + " | ".join(" ".join(map(str, progress.get((dt, p), []))) or "–" for dt in dts) + " |"
        for p in processes]


def _answer_lines(a: dict, title: str, dts: Sequence[float], processes: Sequence[str]) -> list[str]:
    """One measure's tables: the cells (mean ± 95% t half-width, seeds), the differences against
    `white` and between nm-periods and the stationary processes per control step, every process's
    change from each step to the next finer one and from the coarsest to the finest, and the best
    process per step."""
    head, rule = _columns(dts)
    cell = {(c["control_dt"], c["exploration"]): c for c in a.get("cells", [])}
    lines = ["", f"## {title}", "", f"| process | {head} |", rule]
    lines += [f"| {p} | " + " | ".join(_pm(cell[(dt, p)]["mean"], cell[(dt, p)]["ci95"]) + f" (n={cell[(dt, p)]['n']})"
                                       if (dt, p) in cell else "–" for dt in dts) + " |" for p in processes]
    if not a:
        return lines
    fine, coarse = min(dts), max(dts)
    by = _index(a)
    lines += ["", f"* `white` {fine * 1000:g} ms − {coarse * 1000:g} ms: {_d(a.get('white_fine_minus_coarse'))}",
              "", f"| difference | {head} |", rule]
    lines += [f"| {p} − white | " + " | ".join(_d(by.get(((dt, p), (dt, "white")))) for dt in dts) + " |"
              for p in processes if p != "white"]
    lines += [f"| nm-periods − {q} | " + " | ".join(_d(by.get(((dt, "nm-periods"), (dt, q)))) for dt in dts) + " |"
              for q in ("ou", "colored") if q in processes and "nm-periods" in processes]
    lines += ["", "| change | " + " | ".join(processes) + " |", "|---" * (len(processes) + 1) + "|"]
    lines += [f"| {f * 1000:g} ms − {c * 1000:g} ms | " + " | ".join(_d(by.get(((f, p), (c, p)))) for p in processes)
              + " |" for f, c in [*step_pairs(dts), (fine, coarse)]]
    best = a.get("best", {})
    named = ", ".join(f"{float(k) * 1000:g} ms: `{v}`" for k, v in sorted(best.items(), key=lambda kv: -float(kv[0])))
    return lines + ["", f"Best process per control step (highest mean, where every process has finished runs): "
                        f"{named or '–'}."]


def _control_lines(ctl: dict | None) -> list[str]:
    """The samples-per-update control: its cells and differences per measure, and the three
    learning curves by PPO iteration (equal Adam steps and samples per Adam step for the control
    and `white` at the finest step)."""
    if not ctl:
        return []
    k, coarse, fine = ctl["envs_factor"], ctl["coarse"], ctl["fine"]
    lines = ["", "## The samples-per-update control", "",
             f"`white` at {_ms(coarse)} with {k}× the environments ({ctl['num_envs']}) and {k}× the minibatch "
             f"({ctl['batch_size']} unrolls): each Adam step sees as many samples as at {_ms(fine)}, in the same "
             f"number of Adam steps, over {k}× the simulated time per iteration. "
             f"{ctl['finished_runs']} of {ctl['runs']} runs have their budget. Command: `{ctl['command']}`.", "",
             f"| measure (per s) | control | control − `white` {_ms(fine)} | control − `white` {_ms(coarse)} |",
             "|---|---|---|---|"]
    names = {"avg_reward_per_s": "exploring, last iteration", "det_reward_per_s": "deterministic, 10 s",
             "auc_reward_per_s": "exploring, whole run"}
    for key in KEYS:
        a = ctl["answers"][key]
        c = a["cell"]
        lines.append(f"| {names[key]} | " + (f"{_pm(c['mean'], c['ci95'])} (n={c['n']})" if c else "–")
                     + f" | {_d(a['minus_white_fine'])} | {_d(a['minus_white_coarse'])} |")
    curves_ = ctl.get("iterations") or {}
    labels = [(f"control ({_ms(coarse)}, {k}× environments)", "control"), (f"`white` {_ms(fine)}", "white_fine"),
              (f"`white` {_ms(coarse)}", "white_coarse")]
    n = max((len(curves_.get(key) or []) for _, key in labels), default=0)
    if n:
        lines += ["", "Exploring policy's average reward per second by PPO iteration (mean ± 95% t half-width "
                      "over seeds):", "", "| iteration | " + " | ".join(t for t, _ in labels) + " |",
                  "|---" * (len(labels) + 1) + "|"]
        for i in range(n):
            row = []
            for _, key in labels:
                c = curves_.get(key) or []
                row.append(_pm(c[i]["mean"], c[i]["ci95"]) if i < len(c) else "–")
            lines.append(f"| {i + 1} | " + " | ".join(row) + " |")
    return lines


def _snr_lines(snr: Sequence[dict], processes: Sequence[str]) -> list[str]:
    """The gradient's SNR table, coarsest control step first."""
    if not snr:
        return []
    lines = ["", "## The gradient's signal-to-noise ratio (seed 0)", "",
             "PPO's surrogate gradient at θ_old, one estimate per environment from 102.4 s of experience; "
             "tr Cov and the unbiased |E g|² with 95% half-widths over the rollouts; SNR per second = "
             "|E g|² / (tr Cov · seconds per estimate).", "",
             "| δ | process | setting | policy (step) | tr Cov | \\|E g\\|² | SNR per s |",
             "|---|---|---|---|---|---|---|"]
    order = lambda r: (-float(r["control_dt"]), processes.index(r["exploration"])  # noqa: E731
                       if r["exploration"] in processes else 99, r["policy"])
    return lines + [f"| {float(r['control_dt']) * 1000:g} ms | {r['exploration']} | {r['setting']} | "
                    f"{r['policy']} ({r['step']}) | {float(r['trcov']):.3g} ± {float(r['trcov_ci']):.2g} | "
                    f"{float(r['mean_sq']):.3g} ± {float(r['mean_sq_ci']):.2g} | {float(r['snr_per_s']):.3g} |"
                    for r in sorted(snr, key=order)]


def _screen_lines(screen: Sequence[dict], from_grid: Sequence[dict]) -> list[str]:
    """The screen's runs and scores, then the screen's rule applied to the grid's runs."""
    lines = []
    if screen:
        lines += ["", "## The screen (average reward per control step over the second half of its iterations)",
                  "", "| process | setting | seed | iterations | score | chosen |", "|---|---|---|---|---|---|"]
        lines += [f"| {r['exploration']} | {r['field']} = {float(r['value']):g} | {r['seed']} | "
                  f"{r['iterations']} | {float(r['score']):+.3f} | {'yes' if r['chosen'] is True else ''} |"
                  for r in screen]
    if from_grid:
        lines += ["", "The screen's rule applied to the grid's runs at the screen's control step (the screen's "
                      "seeds, their first iterations): `white` is the limit of every correlated process as its "
                      "correlation shrinks; a chosen setting repeats its screen runs.", "",
                  "| process | setting | seed | score |", "|---|---|---|---|"]
        lines += [f"| {r['exploration']} | {r['setting']} | {r['seed']} | {float(r['score']):+.3f} |" for r in from_grid]
    return lines


def _command_lines(commands: dict) -> list[str]:
    """One `nmrl sweep` command per grid cell that runs it again from scratch."""
    if not commands:
        return []
    return ["", "## Running a cell again from scratch", "",
            "The same program and seeds as the study's cell, so the same numbers on the same machine "
            "(a cell's runs and the screen's runs of the same setting and seed agree to the last bit in "
            "their common iterations); on another machine the compiled program's floating point differs "
            "and a rerun agrees only statistically, as does a point run alone by `nmrl train` (another "
            "program). A smaller `--steps` stops earlier.", ""] + [
        f"* {k.split('/')[1]} at {float(k.split('/')[0]) * 1000:g} ms: `{v}`" for k, v in commands.items()]


#: the measures answers.md shows, by their summary.json key
MEASURES = (("answers", "Exploring policy: average reward per second over the last iteration"),
            ("answers_deterministic", "Deterministic policy: average reward per second over 10 s"),
            ("answers_auc", "Exploring policy: average reward per second over the whole run (the learning "
                            "curve's mean)"))


def report(summary: dict, results: Sequence[dict], screen: Sequence[dict], snr: Sequence[dict],
           dts: Sequence[float], processes: Sequence[str], iterations: int) -> str:
    """The study's numbers as a Markdown page (results/exploration/answers.md): progress, the
    answers in words (:func:`plain_answers`), the final average reward per second of the exploring
    and the deterministic policy per cell (mean ± 95% t half-width over the finished seeds) with
    the Welch differences, the gradient's SNR, the screen and the re-run commands. Made of
    ``summary`` (:func:`answers` of the finished runs) and the tables."""
    dts = sorted(dts, reverse=True)
    done = finished(results, iterations)
    lines = ["# The exploration × control-step study: its numbers",
             "",
             f"Written by `scripts/publish_exploration.py` from `results.csv`, `summary.json`, `snr.csv` and "
             f"`screen.csv`; the design and the discussion: docs/exploration-study.md. **{len(done)} of "
             f"{len(results)} grid runs** started so far have their budget ({iterations} PPO iterations) or "
             f"diverged; only those enter the numbers below. Rewards per second = mean r_t / 20 ms at every "
             f"δ; ± is the 95% t half-width over seeds (differences: Welch).", ""]
    lines += _progress_lines(results, dts, processes) + [""] + plain_answers(summary, dts, processes)
    for key, title in MEASURES:
        lines += _answer_lines(summary.get(key) or {}, title, dts, processes)
    lines += _control_lines(summary.get("control"))
    lines += _snr_lines(snr, processes) + _screen_lines(screen, summary.get("screen_from_grid") or [])
    lines += _command_lines(summary.get("commands") or {})
    return "\n".join(lines) + "\n"


def best_and_worst(rows: Sequence[dict], dt: float, processes: Sequence[str], key: str = "avg_reward_per_s"
                   ) -> list[tuple[str, int]] | None:
    """``[(best process, its median seed), (worst process, its median seed)]`` at control step
    ``dt`` by the mean of ``key`` over seeds (the median seed: the run nearest the cell's median,
    the lower one of an even count); None unless every process has runs there."""
    c = {p: [(float(r[key]), int(r["seed"])) for r in rows if float(r["control_dt"]) == dt
             and r["exploration"] == p and math.isfinite(float(r[key]))] for p in processes}
    if any(not v for v in c.values()):
        return None
    mean = {p: np.mean([x for x, _ in v]) for p, v in c.items()}
    out = []
    for p in (max(mean, key=mean.get), min(mean, key=mean.get)):
        v = sorted(c[p])
        out.append((p, v[(len(v) - 1) // 2][1]))
    return out


# ------------------------------------------------------------------------------------ publishing
#: what a fresh clone needs of every cell to continue it, and what the answers are made of
PUBLISHED_FILES = ("sweep.json", "config.json", "metrics.jsonl", "compact.npz", "eval.json")
TOP_FILES = ("study.json", "results.csv", "control.csv", "screen.csv", "snr.csv", "summary.json")


def publish(src: pathlib.Path, dest: pathlib.Path) -> list[pathlib.Path]:
    """Copy the study ``src``'s tables and every cell's continuation files (sweep.json; per point
    config, metrics, compact state, the mid-training state under ``mid/``, ``eval/eval.json``) to
    ``dest`` (tables at the top, cells under ``dest/runs/``), each file atomically; returns the
    files written. Checkpoints stay behind (the compact states continue a run)."""
    src, dest = pathlib.Path(src), pathlib.Path(dest)
    written = []
    for name in TOP_FILES:
        if (src / name).is_file():
            store.atomic_copy(src / name, dest / name)
            written.append(dest / name)
    if (src / "study.json").is_file():
        store.atomic_copy(src / "study.json", dest / "runs" / "study.json")
    for phase in ("grid", "screen", "control"):
        for f in sorted((src / phase).rglob("*")) if (src / phase).is_dir() else []:
            rel = f.relative_to(src)
            if f.is_file() and f.name in PUBLISHED_FILES and "checkpoints" not in rel.parts:
                store.atomic_copy(f, dest / "runs" / rel)
                written.append(dest / "runs" / rel)
    return written


def curves(src: pathlib.Path, rows: Sequence[dict]) -> dict[tuple[float, str], list[tuple[np.ndarray, np.ndarray]]]:
    """``{(control_dt, exploration): [(simulated s summed over environments, avg reward per s)]}``,
    one pair per run of ``rows`` (the grid's points: ``grid/dt{dt}/{exploration}/points/s{seed}``)."""
    out: dict = {}
    for r in rows:
        dt = float(r["control_dt"])
        p = pathlib.Path(src) / "grid" / f"dt{dt:g}" / r["exploration"] / "points" / f"s{int(r['seed'])}"
        m = store.read_metrics(p)
        if not m:
            continue
        n = int(r["control_steps"]) / max(1, int(m[-1]["step"]))  # environments
        x = np.array([q["step"] for q in m], float) * n * dt
        y = np.array([q["avg_reward"] for q in m], float) / DELTA_0
        out.setdefault((dt, r["exploration"]), []).append((x, y))
    return out


def _save(fig, path: pathlib.Path) -> pathlib.Path:
    """Write ``fig`` to ``path`` atomically (a reader never sees half a PNG) and close it."""
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with store.atomic_path(path) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return path


def draw_control(ctl: dict, path: pathlib.Path) -> pathlib.Path:
    """The samples-per-update control's learning curves (``control.png``): the exploring policy's
    average reward per second of the control and of `white` at the finest and the coarsest control
    step (mean and 95% t-band over seeds), against the PPO iteration (the same Adam steps; the
    control's and the finest step's with the same samples per Adam step) and against one run's
    simulated seconds (the control has ``envs_factor`` times as many per iteration)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    series = [("control", f"white {_ms(ctl['coarse'])}, {ctl['envs_factor']}× environments (control)", "C3", "-"),
              ("white_fine", f"white {_ms(ctl['fine'])}", "C0", "-"),
              ("white_coarse", f"white {_ms(ctl['coarse'])}", "C0", "--")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110, sharey=True)
    for key, label, color, ls in series:
        c = (ctl.get("iterations") or {}).get(key) or []
        if not c:
            continue
        it = np.array([r["iteration"] for r in c], float)
        m, h = np.array([r["mean"] for r in c]), np.array([r["ci95"] for r in c])
        for ax, x in zip(axes, (it, it * ctl["seconds_per_iteration"][key])):
            ax.plot(x, m, color=color, ls=ls, lw=2, label=f"{label} ({c[0]['runs']} seeds)")
            ax.fill_between(x, m - h, m + h, color=color, alpha=0.15, lw=0)
    axes[0].set_xlabel("PPO iteration (the same Adam steps)")
    axes[1].set_xlabel("simulated seconds of one run (all environments)")
    axes[0].set_ylabel("average reward per second (exploring)")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("The samples-per-update control", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def draw(src: pathlib.Path, rows: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
         path: pathlib.Path) -> pathlib.Path:
    """Learning curves, one panel per control step: every process's mean over seeds (thin lines:
    each seed), average reward per second of the exploring policy against simulated seconds."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    cv = curves(src, rows)
    dts = sorted(dts, reverse=True)
    fig, axes = plt.subplots(1, len(dts), figsize=(5 * len(dts), 4.2), dpi=110, sharey=True, squeeze=False)
    for ax, dt in zip(axes[0], dts):
        for i, p in enumerate(processes):
            runs = cv.get((dt, p), [])
            for x, y in runs:
                ax.plot(x, y, color=f"C{i}", lw=0.6, alpha=0.35)
            if runs:
                k = min(len(x) for x, _ in runs)
                ax.plot(runs[0][0][:k], np.mean([y[:k] for _, y in runs], 0), color=f"C{i}", lw=2,
                        label=f"{p} ({len(runs)} seeds)")
        ax.set_title(f"δ = {dt * 1000:g} ms")
        ax.set_xlabel("simulated seconds (all environments)")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    axes[0][0].set_ylabel("average reward per second (exploring)")
    fig.tight_layout()
    return _save(fig, path)



def draw_summary(rows: Sequence[dict], snr: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
                 iterations: int, path: pathlib.Path) -> pathlib.Path:
    """The thesis in one figure (``summary.png``): the exploring and the deterministic policy's
    final average reward per second against the control step, one line per process (mean and 95%
    t-interval over the finished seeds; x: each seed), and the gradient's SNR per second of
    experience and tr Cov (seed 0; solid: mid-training, dashed: initial policy)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    done = finished(rows, iterations)
    dts = sorted(dts, reverse=True)
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.6), dpi=110)
    for ax, key, title in ((axes[0], "avg_reward_per_s", "exploring policy, last iteration"),
                           (axes[1], "det_reward_per_s", "deterministic policy, 10 s")):
        c = cells(done, key)
        for i, p in enumerate(processes):
            xs, ms, hs = [], [], []
            for dt in dts:
                v = c.get((dt, p))
                if v is None:
                    continue
                m, h = stats.mean_ci95(v)
                xs.append(dt), ms.append(m), hs.append(h)
                shift = 1 + 0.03 * (i - (len(processes) - 1) / 2)
                ax.scatter([dt * shift] * len(v), v, s=14, color=f"C{i}", alpha=0.5, marker="x")
            if xs:
                ax.errorbar(xs, ms, yerr=hs, marker="o", capsize=4, color=f"C{i}", label=f"{p} (mean, 95% CI)")
        ax.set_title(title)
        ax.set_ylabel("average reward per second")
    for ax, key, title in ((axes[2], "snr_per_s", "gradient SNR per second of experience"),
                           (axes[3], "trcov", "tr Cov of the per-environment gradient")):
        for i, p in enumerate(processes):
            for policy, ls in (("mid", "-"), ("initial", "--")):
                rr = sorted((r for r in snr if r["exploration"] == p and r["policy"] == policy),
                            key=lambda r: -float(r["control_dt"]))
                if rr:
                    ax.errorbar([float(r["control_dt"]) for r in rr], [float(r[key]) for r in rr],
                                yerr=[float(r["trcov_ci"]) for r in rr] if key == "trcov" else None,
                                marker="o", ls=ls, color=f"C{i}", capsize=3, label=f"{p}, {policy}")
        ax.set_yscale("log" if key == "trcov" else "symlog", **({} if key == "trcov" else {"linthresh": 1e-4}))
        ax.set_title(title)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(dts, [f"{dt * 1000:g}" for dt in dts])
        ax.minorticks_off()
        ax.set_xlim(max(dts) * 1.25, min(dts) / 1.25)  # coarse to fine, every control step in view
        ax.set_xlabel("control step δ [ms]")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "nothing finished yet", ha="center", va="center", transform=ax.transAxes, color="0.4")
    fig.tight_layout()
    return _save(fig, path)



def draw_gaits(gaits: Sequence[tuple[str, pathlib.Path]], path: pathlib.Path, every_s: float = 0.1,
               span_s: float = 3.0) -> pathlib.Path:
    """The strobes of the given gaits (``(title, trajectory.npz)`` as `nmrl eval` writes it) one above
    the other at one scale: every panel spans the same metres in x and y, so how far each robot gets
    in ``span_s`` seconds, and the height it runs at, compare at a glance."""
    plt = gait_pictures.pyplot()
    runs = []
    for title, f in gaits:
        with np.load(f) as z:
            pos, dt = np.asarray(z["pos"], float), float(z["control_dt"])
        frames = gait_pictures.strobe_frames(pos, dt, every_s, span_s)
        runs.append((title, pos, dt, frames, gait_pictures.strobe_extent(pos, frames)))
    x_lo = min(r[4][0] for r in runs)
    x_hi = max(r[4][1] for r in runs)
    y_hi = max(r[4][2] for r in runs)
    scale = min(1.6, 20.0 / (x_hi - x_lo))  # inches per metre, the widest picture at most 20 in
    fig, axes = plt.subplots(len(runs), 1, squeeze=False, dpi=100,
                             figsize=(scale * (x_hi - x_lo) + 1.0, len(runs) * (scale * (y_hi + 0.1) + 0.9)))
    for ax, (title, pos, dt, frames, _) in zip(axes[:, 0], runs):
        gait_pictures.draw_strobe(ax, pos, frames, dt, (x_lo, x_hi, y_hi), every_s, title)
    fig.tight_layout()
    return _save(fig, path)


__all__: Sequence[str] = ("RESULT_COLUMNS", "SCREEN_COLUMNS", "score", "choose", "eval_summary", "run_row", "cells",
                          "cell_table", "diff", "step_pairs", "answers", "finished", "report", "best_and_worst", "publish",
                          "curves", "draw", "draw_summary", "draw_gaits", "draw_control", "control_answers",
                          "iteration_means")
