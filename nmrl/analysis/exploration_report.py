"""The first exploration study's page of numbers (results/exploration/answers.md) as Markdown tables.

:func:`report` writes the tables of ``summary.json``'s numbers (nmrl.analysis.exploration_answers):
progress, the final average reward per second of the exploring and the deterministic policy per
cell (mean ± 95% t half-width over the finished seeds) with the Welch differences, the
samples-per-update control, the gradient's SNR, the screen and the re-run commands. The answers in
words are the study's reading of these numbers: prose, given to :func:`report` as lines (the
published page takes them from docs/exploration-study.md).
"""

from __future__ import annotations

import math
from typing import Sequence

from nmrl.analysis.exploration_answers import KEYS, finished, step_pairs


def ms(dt: float) -> str:
    """A control step in milliseconds, as the tables and words name it."""
    return f"{dt * 1000:g} ms"


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
             f"`white` at {ms(coarse)} with {k}× the environments ({ctl['num_envs']}) and {k}× the minibatch "
             f"({ctl['batch_size']} unrolls): each Adam step sees as many samples as at {ms(fine)}, in the same "
             f"number of Adam steps, over {k}× the simulated time per iteration. "
             f"{ctl['finished_runs']} of {ctl['runs']} runs have their budget. Command: `{ctl['command']}`.", "",
             f"| measure (per s) | control | control − `white` {ms(fine)} | control − `white` {ms(coarse)} |",
             "|---|---|---|---|"]
    names = {"avg_reward_per_s": "exploring, last iteration", "det_reward_per_s": "deterministic, 10 s",
             "auc_reward_per_s": "exploring, whole run"}
    for key in KEYS:
        a = ctl["answers"][key]
        c = a["cell"]
        lines.append(f"| {names[key]} | " + (f"{_pm(c['mean'], c['ci95'])} (n={c['n']})" if c else "–")
                     + f" | {_d(a['minus_white_fine'])} | {_d(a['minus_white_coarse'])} |")
    curves_ = ctl.get("iterations") or {}
    labels = [(f"control ({ms(coarse)}, {k}× environments)", "control"), (f"`white` {ms(fine)}", "white_fine"),
              (f"`white` {ms(coarse)}", "white_coarse")]
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
           dts: Sequence[float], processes: Sequence[str], iterations: int, said: Sequence[str] = ()) -> str:
    """The study's numbers as a Markdown page: progress, the answers in words ``said`` (lines of
    Markdown), then one set of tables per measure of :data:`MEASURES`, the
    control, the SNR, the screen and the re-run commands. Made of ``summary`` (the numbers of the
    finished runs) and the tables."""
    dts = sorted(dts, reverse=True)
    done = finished(results, iterations)
    lines = ["# The exploration × control-step study: its numbers",
             "",
             f"Written by `scripts/publish/publish_exploration.py` from `results.csv`, `summary.json`, `snr.csv` and "
             f"`screen.csv`; the design and the discussion: docs/exploration-study.md. **{len(done)} of "
             f"{len(results)} grid runs** started so far have their budget ({iterations} PPO iterations) or "
             f"diverged; only those enter the numbers below. Rewards per second = mean r_t / 20 ms at every "
             f"δ; ± is the 95% t half-width over seeds (differences: Welch).", ""]
    lines += _progress_lines(results, dts, processes) + [""] + list(said)
    for key, title in MEASURES:
        lines += _answer_lines(summary.get(key) or {}, title, dts, processes)
    lines += _control_lines(summary.get("control"))
    lines += _snr_lines(snr, processes) + _screen_lines(screen, summary.get("screen_from_grid") or [])
    lines += _command_lines(summary.get("commands") or {})
    return "\n".join(lines) + "\n"
