"""The paper's thesis with a modern learner: exploration process x control step, native PPO.

The paper (abstract, Sec. III, eq. (1)) claims that a stationary policy loses its exploration power
as the control step delta shrinks and that nm-periods of a fixed duration keep it. This study
runs the native PPO (docs/ppo.md, settings in seconds) with every process of nmrl.explore at
delta in ``dts`` on the same physics, at an equal budget of PPO iterations (one iteration holds
102.4 s of experience per environment at every delta), and measures the learning, the
deterministic policies and the gradient's signal-to-noise ratio (nmrl/experiments/ppo_gradsnr.py).
docs/exploration-study.md gives the design, the sizing and the answers.

Order of work (each step a cell: an ``nmrl sweep`` directory, resumable on its own):

1. ``grid/dt{dts[0]}/white``: the white-noise cell at the coarsest delta, the check of the study's
   network sizes against the Brax-sized validation (results/ppo/).
2. ``screen/dt{screen_dt}/{process}``: per correlated process, its settings (``SCREEN``) x
   ``screen_seeds`` for ``screen_iterations``; the rule (nmrl.analysis.exploration_results.choose)
   fixes one setting per process, written to ``screen.csv``.
3. ``grid/dt{dt}/{process}`` for every delta in ``dts`` order (the stages) and process: ``seeds``
   seeds at the chosen setting for ``iterations``. Every grid cell runs to half its budget, keeps
   each point's compact state there (``points/<p>/mid/``, for the mid-training SNR), then finishes.
   Every finished point is evaluated (deterministic policy, ``eval_seconds`` from seed 0).
4. ``snr.csv``: the gradient's SNR per (delta, process) at the initial policy and at mid-training
   (seed 0), after that delta's grid cells, before the next delta's.
5. ``control/dt{max(dts)}/white``: the samples-per-update control (:func:`control_cell`), `white`
   at the coarsest delta with ``max(dts) / min(dts)`` times the environments and minibatch, ``seeds``
   seeds for ``iterations``, evaluated; its rows in ``control.csv``.

``results.csv`` (one row per grid run) and ``summary.json`` (the answers) are rewritten after every
cell. Everything resumes where it stopped: run the same command again; on a fresh clone
``--published`` seeds the cells from their committed compact states.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import shutil
import sys
import time
from typing import Sequence

from nmrl import learners
from nmrl.paper.env import PHYSICS, PHYSICS_HELP
from nmrl.analysis import exploration_results as xr
from nmrl.experiments import sweep
from nmrl.runs import bounds, checkpoint, command, lock, parser, signals, store

PPOConfig = learners.get("ppo").config
SPEC_FILE = "study.json"
PROCESSES = ("white", "nm-periods", "ou", "colored")
#: the paper's alpha = 0.8 per 20 ms step as a correlation time: -0.02 s / ln 0.8
NM_CORR_TIME_S = 0.08963
#: per correlated process: the field the screen varies and its values (seconds; colored: beta)
SCREEN = {"nm-periods": ("period_s", (0.1, 0.2, 0.4)),
          "ou": ("corr_time_s", (0.045, 0.09, 0.18)),
          "colored": ("beta", (0.5, 1.0, 2.0))}
PHASES = ("grid", "screen", "eval", "snr", "control")
SNR_COLUMNS = ("control_dt", "exploration", "setting", "policy", "step", "estimates", "batches",
               "seconds_per_estimate", "trcov", "trcov_ci", "mean_sq", "mean_sq_ci", "snr_per_s")


class StudyError(Exception):
    """The study cannot start or continue (the message says why)."""


def physics_timestep() -> float:
    """The reference physics' timestep [s] (the MJCF's, read with MuJoCo C: no MJX, no compile)."""
    import mujoco

    from nmrl.paper.env import MODEL_PATH

    return float(mujoco.MjModel.from_xml_path(str(MODEL_PATH)).opt.timestep)


@dataclasses.dataclass(frozen=True)
class StudySpec:
    dts: tuple[float, ...] = (0.02, 0.005, 0.01)  #: control steps [s], in the order they run
    seeds: int = 4
    iterations: int = 16  #: PPO iterations per grid run (102.4 s of experience per environment each)
    screen_dt: float = 0.005
    screen_seeds: int = 2
    screen_iterations: int = 4
    num_envs: int = 64
    value_layers: int = 2
    value_width: int = 64
    batch_size: int = 512  #: unrolls per minibatch (PPO's defaults: docs/ppo.md)
    num_minibatches: int = 32
    epochs: int = 8
    checkpoint_every: int = 1
    eval_seconds: float = 10.0
    snr_batches: int = 4
    physics: str = "mjx"  #: every run's physics engine (nmrl/paper/env.py PHYSICS)
    env: str = "paper-cheetah"  #: every run's environment (nmrl.tasks.ENVS; docs/tasks.md)

    def validate(self) -> None:
        def bad(name, allowed):
            return ValueError(f"{name}={getattr(self, name)!r} is invalid: {allowed}")

        if self.physics not in PHYSICS:
            raise bad("physics", f"choose one of {', '.join(PHYSICS)}")

        bounds.control_steps("dts", self.dts, "0.02 0.005 0.01")
        bounds.positive_ints(self, ("seeds", "iterations", "screen_seeds", "screen_iterations", "num_envs",
                                    "value_layers", "value_width", "batch_size", "num_minibatches", "epochs",
                                    "checkpoint_every"))
        if self.iterations < 2:
            raise bad("iterations", "must be >= 2 (the mid-training state is taken at half)")
        if not (isinstance(self.snr_batches, int) and self.snr_batches >= 2):
            raise bad("snr_batches", "must be an integer >= 2 (an interval needs 2 batches)")
        if not (isinstance(self.eval_seconds, (int, float)) and self.eval_seconds > 0):
            raise bad("eval_seconds", "must be > 0 s")
        step = physics_timestep()
        for dt in self.dts + (self.screen_dt,):
            n = dt / step
            if self.env == "paper-cheetah" and (abs(n - round(n)) > 1e-6 or round(n) < 1):  # a task checks its own
                raise ValueError(f"control step {dt:g} s is invalid: must be a positive multiple of the physics "
                                 f"timestep {step:g} s")
            for proc in PROCESSES:
                learners.get("ppo").validate(self.config(dt, proc, **self.default_setting(proc)))

    @staticmethod
    def default_setting(process: str) -> dict:
        """The setting a process runs at before the screen has chosen (the screen's middle value)."""
        if process not in SCREEN:
            return {}
        f, vals = SCREEN[process]
        return {f: vals[len(vals) // 2]}

    def config(self, dt: float, process: str, **setting) -> PPOConfig:
        """A run's config: the native PPO on the study's env with its settings in seconds, the study's
        networks, reward scale delta / 0.02 s on the paper's robot (the value's scale kept, docs/ppo.md;
        a task's rewards already are rates integrated over the step: scale 1), nm-periods with the
        paper's correlation time unless given."""
        extra = {"corr_time_s": NM_CORR_TIME_S} if process == "nm-periods" and "corr_time_s" not in setting else {}
        if self.env != "paper-cheetah":
            extra["env"] = self.env
        scale = dt / xr.DELTA_0 if self.env == "paper-cheetah" else 1.0
        return PPOConfig(exploration=process, control_dt=dt, reward_scale=scale, num_envs=self.num_envs,
                         value_layers=self.value_layers, value_width=self.value_width, batch_size=self.batch_size,
                         num_minibatches=self.num_minibatches, epochs=self.epochs, physics=self.physics, **extra,
                         **setting)

    def step_s(self, dt: float) -> float:
        """The seconds a run's per-step reward at ``dt`` is a rate over: the paper's 0.02 s on its robot
        (its rewards (8)-(14) are rates), ``dt`` on a task (its rewards are integrated over the step)."""
        return xr.DELTA_0 if self.env == "paper-cheetah" else dt

    def iteration_steps(self, dt: float) -> int:
        return self.config(dt, "white").resolved().iteration_steps

    def to_json(self) -> dict:
        """The spec as study.json holds it (the paper's robot, every study's env before tasks, unnamed)."""
        d = dataclasses.asdict(self)
        d["dts"] = list(self.dts)
        if d["env"] == "paper-cheetah":
            del d["env"]
        return d

    @staticmethod
    def from_json(d: dict) -> "StudySpec":
        d = dict(d)
        d["dts"] = tuple(d["dts"])
        return StudySpec(**d)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One sweep of the study: ``field`` (None: seeds only) over ``values`` x ``seeds``."""

    phase: str  #: "screen" or "grid"
    dt: float
    process: str
    field: str | None
    values: tuple
    seeds: int
    iterations: int
    setting: tuple = ()  #: the fixed (field, value) pairs of the process
    envs_factor: int = 1  #: environments and minibatch unrolls, times the study's

    def dir(self, out: pathlib.Path) -> pathlib.Path:
        return out / self.phase / f"dt{self.dt:g}" / self.process

    def sweep_spec(self, spec: StudySpec, iterations: int | None = None) -> sweep.SweepSpec:
        steps = (iterations or self.iterations) * spec.iteration_steps(self.dt)
        base = dataclasses.replace(spec.config(self.dt, self.process, **dict(self.setting)), steps=steps,
                                   num_envs=spec.num_envs * self.envs_factor,
                                   batch_size=spec.batch_size * self.envs_factor)
        return sweep.SweepSpec(ls=self.values, seeds=self.seeds, base=base, field=self.field)

    def points(self) -> list[str]:
        return [sweep.point_name(v, s, self.field) for v in self.values for s in range(self.seeds)]

    def command(self, spec: StudySpec, out: str = "runs/rerun") -> str:
        """The ``nmrl sweep`` command that runs this grid cell again from scratch into ``out``: the
        same program and seeds, so the same numbers (every config field that differs from PPO's
        default, as its option)."""
        if self.field is not None:
            raise ValueError(f"{self.phase} cell {self.process} varies {self.field}: only a grid cell is one "
                             f"nmrl sweep of seeds")
        base, default = self.sweep_spec(spec).base, PPOConfig()
        given = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)
                 if f.name != "seed" and getattr(base, f.name) != getattr(default, f.name)}
        flags = [f"--{k.replace('_', '-')} {v if isinstance(v, str) else repr(v)}" for k, v in given.items()]
        return " ".join(["nmrl sweep --learner ppo", *flags, f"--seeds {self.seeds}", "--checkpoint-every 1",
                         f"--out {out}"])


def screen_cells(spec: StudySpec) -> list[Cell]:
    out = []
    for proc, (f, vals) in SCREEN.items():
        setting = (("corr_time_s", NM_CORR_TIME_S),) if proc == "nm-periods" else ()
        out.append(Cell("screen", spec.screen_dt, proc, f, tuple(vals), spec.screen_seeds, spec.screen_iterations,
                        setting))
    return out


def grid_cell(spec: StudySpec, dt: float, process: str, chosen: dict[str, tuple[str, float]]) -> Cell:
    setting: tuple = ()
    if process in SCREEN:
        f, v = chosen[process]
        setting = ((f, v),) + ((("corr_time_s", NM_CORR_TIME_S),) if process == "nm-periods" else ())
    return Cell("grid", dt, process, None, (None,), spec.seeds, spec.iterations, setting)


def control_cell(spec: StudySpec) -> Cell | None:
    """The samples-per-update control: at the finest delta an iteration's 102.4 s per environment
    hold ``max(dts) / min(dts)`` times the samples of the coarsest, so every Adam step of the same
    ``epochs * num_minibatches`` sees that many times more. `white` at the coarsest delta with that
    many times the environments and minibatch unrolls has the finest delta's samples per Adam step
    and Adam steps (and that many times the simulated time): against `white` at the finest delta it
    separates the control step from the samples per update. None with one control step (or when
    the ratio is not a whole number > 1)."""
    coarse, fine = max(spec.dts), min(spec.dts)
    k = round(coarse / fine)
    if k < 2 or abs(coarse / fine - k) > 1e-6:
        return None
    return Cell("control", coarse, "white", None, (None,), spec.seeds, spec.iterations, (), k)


def setting_label(cell: Cell) -> str:
    return ",".join(f"{k}={v:g}" for k, v in cell.setting) or "-"


# ------------------------------------------------------------------------------------------ cells
def _steps_done(point: pathlib.Path) -> tuple[int, bool]:
    m = store.read_metrics(point)
    return (int(m[-1]["step"]) if m else 0), any(store.is_diverged(r) for r in m)


def _comparable(cfg) -> object:
    return dataclasses.replace(cfg.resolved(), steps=None, trials=None, seed=0)


def run_cell(out: pathlib.Path, cell: Cell, spec: StudySpec, *, iterations: int | None = None,
             progress: bool = True) -> bool:
    """Run ``cell`` to ``iterations`` (default: its budget); False if every point was already there.
    A cell directory holding a sweep of other settings is refused (StudyError)."""
    d = cell.dir(out)
    target = cell.sweep_spec(spec, iterations)
    steps = target.base.steps
    if (d / sweep.SPEC_FILE).exists():
        saved = sweep.load_spec(d)
        if (_comparable(saved.base) != _comparable(target.base) or tuple(saved.ls) != tuple(target.ls)
                or saved.seeds != target.seeds or saved.field != target.field):
            raise StudyError(f"{d} holds a sweep with other settings than the study's {cell.phase} cell "
                             f"({cell.process} at {cell.dt:g} s); move it away or choose another --out")
        done = [_steps_done(d / "points" / p) for p in cell.points()]
        if all(s >= steps or div for s, div in done):
            return False
        resume = True
    else:
        resume = False
    if progress:
        print(f"[{cell.phase} dt={cell.dt:g} {cell.process} {setting_label(cell)}] "
              f"{'resuming' if resume else 'starting'} to {steps:,} control steps per environment",
              file=sys.stderr, flush=True)
    sweep.run_sweep(target, d, resume=resume, progress=progress, checkpoint_every=spec.checkpoint_every,
                    plot=False)
    return True


def keep_mid(out: pathlib.Path, cell: Cell, spec: StudySpec) -> None:
    """Copy each point's compact state at half the budget to ``points/<p>/mid/`` (once)."""
    half = (cell.iterations // 2) * spec.iteration_steps(cell.dt)
    for p in cell.points():
        src = cell.dir(out) / "points" / p
        dst = src / "mid"
        if (dst / checkpoint.COMPACT_FILE).exists():
            continue
        if not checkpoint.has_compact(src):
            continue
        _, arrays = checkpoint.load_compact(src)
        if int(arrays["step"]) != half:
            continue
        dst.mkdir(exist_ok=True)
        for f in (checkpoint.RUN_CONFIG, checkpoint.COMPACT_FILE):
            store.atomic_copy(src / f, dst / f)


def evaluate_points(out: pathlib.Path, cell: Cell, spec: StudySpec, progress: bool = True) -> None:
    """Evaluate every finished point's deterministic policy once (``points/<p>/eval/eval.json``)."""
    from nmrl.analysis import evaluate

    steps = cell.iterations * spec.iteration_steps(cell.dt)
    for p in cell.points():
        d = cell.dir(out) / "points" / p
        step, diverged = _steps_done(d)
        if step < steps and not diverged:
            continue
        ev = xr.eval_summary(d)
        if ev is not None and ev.get("step") == step:
            continue
        r = evaluate.evaluate(d, seconds=spec.eval_seconds, seed=0, render=False)
        if progress:
            print(f"[eval dt={cell.dt:g} {cell.process} {p}] deterministic avg reward "
                  f"{xr.det_reward(r['deterministic']):+.3f}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------ study
def _check_spec(out: pathlib.Path, spec: StudySpec) -> None:
    path = out / SPEC_FILE
    if path.exists():
        saved = StudySpec.from_json(json.loads(path.read_text()))
        diff = [f.name for f in dataclasses.fields(spec) if getattr(saved, f.name) != getattr(spec, f.name)]
        longer = {"iterations"} if spec.iterations > saved.iterations else set()
        if set(diff) - longer:
            raise StudyError(f"{out} holds a study with other settings ({', '.join(diff)}); continue it with the "
                             f"same options (a larger --iterations may be given) or choose another --out")
        if diff:
            store.atomic_write_json(path, spec.to_json())
    else:
        out.mkdir(parents=True, exist_ok=True)
        store.atomic_write_json(path, spec.to_json())


def screen_rows(out: pathlib.Path, spec: StudySpec) -> list[dict]:
    rows = []
    for c in screen_cells(spec):
        for v in c.values:
            for s in range(c.seeds):
                m = store.read_metrics(c.dir(out) / "points" / sweep.point_name(v, s, c.field))
                rows.append({"exploration": c.process, "field": c.field, "value": v, "seed": s,
                             "iterations": (int(m[-1]["step"]) if m else 0) // spec.iteration_steps(c.dt),
                             "score": xr.score(m), "diverged": any(store.is_diverged(r) for r in m)})
    return rows


def screen_from_grid(out: pathlib.Path, spec: StudySpec, chosen: dict | None) -> list[dict]:
    """The screen's rule applied to the grid's runs at the screen's control step: the seeds the
    screen ran, their first ``screen_iterations`` iterations. For `white` (the limit of every
    correlated process as its correlation shrinks) it is the reference the screen has no run of;
    for a chosen setting it is the screen's own run again (the same config and seed)."""
    if spec.screen_dt not in spec.dts:
        return []
    rows = []
    for c in grid_cells(spec, chosen):
        if c.dt != spec.screen_dt:
            continue
        for s in range(min(spec.screen_seeds, c.seeds)):
            m = store.read_metrics(c.dir(out) / "points" / sweep.point_name(None, s, None))
            if len(m) >= spec.screen_iterations:
                rows.append({"exploration": c.process, "setting": setting_label(c), "seed": s,
                             "score": xr.score(m[:spec.screen_iterations])})
    return rows


def chosen_settings(out: pathlib.Path, spec: StudySpec) -> dict[str, tuple[str, float]] | None:
    """The screen's choice per correlated process, None until every screen run has its budget."""
    rows = screen_rows(out, spec)
    if any(r["iterations"] < spec.screen_iterations and not r["diverged"] for r in rows):
        return None
    chosen = xr.choose(rows)
    for r in rows:
        r["chosen"] = chosen[r["exploration"]][1] == r["value"]
    store.write_csv(out / "screen.csv", xr.SCREEN_COLUMNS, rows)
    return chosen


def grid_cells(spec: StudySpec, chosen: dict | None) -> list[Cell]:
    """Every grid cell in run order; those of correlated processes only once ``chosen`` exists."""
    return [grid_cell(spec, dt, p, chosen or {}) for dt in spec.dts for p in PROCESSES
            if p == "white" or chosen is not None]


def result_rows(out: pathlib.Path, spec: StudySpec, cells: Sequence[Cell]) -> list[dict]:
    """One results.csv row per run of ``cells`` that has metrics."""
    rows = []
    for c in cells:
        for s in range(c.seeds):
            r = xr.run_row(c.dir(out) / "points" / sweep.point_name(None, s, None), exploration=c.process,
                           setting=setting_label(c), control_dt=c.dt, seed=s,
                           num_envs=spec.num_envs * c.envs_factor, iteration_steps=spec.iteration_steps(c.dt),
                           step_s=spec.step_s(c.dt))
            if r is not None:
                rows.append(r)
    return rows


def control_summary(out: pathlib.Path, spec: StudySpec, cell: Cell, grid: Sequence[dict]) -> dict | None:
    """The control's rows (``control.csv``) and its answers against `white` at the finest and the
    coarsest delta (nmrl.analysis.exploration_results.control_answers, finished runs only), with
    the three learning curves by iteration; None until the control has a run."""
    rows = result_rows(out, spec, [cell])
    if not rows:
        return None
    store.write_csv(out / "control.csv", xr.RESULT_COLUMNS, rows)
    coarse, fine = max(spec.dts), min(spec.dts)
    done = xr.finished(rows, spec.iterations)

    def runs(c: Cell) -> list[list[dict]]:
        return [m for s in range(c.seeds) for m in [store.read_metrics(c.dir(out) / "points" / f"s{s}")] if m]

    white = {dt: grid_cell(spec, dt, "white", {}) for dt in (coarse, fine)}
    base = cell.sweep_spec(spec).base
    return {"envs_factor": cell.envs_factor, "coarse": coarse, "fine": fine, "num_envs": base.num_envs,
            "batch_size": base.batch_size, "runs": len(rows), "finished_runs": len(done),
            "seconds_per_iteration": {"control": base.num_envs * spec.iteration_steps(coarse) * coarse,
                                      **{k: spec.num_envs * spec.iteration_steps(dt) * dt
                                         for k, dt in (("white_fine", fine), ("white_coarse", coarse))}},
            "command": cell.command(spec, out=f"runs/rerun/control/dt{coarse:g}/white"),
            "answers": xr.control_answers(done, grid, coarse, fine),
            "iterations": {"control": xr.iteration_means(runs(cell), spec.step_s(coarse)),
                           "white_fine": xr.iteration_means(runs(white[fine]), spec.step_s(fine)),
                           "white_coarse": xr.iteration_means(runs(white[coarse]), spec.step_s(coarse))}}


def write_results(out: pathlib.Path, spec: StudySpec, chosen: dict | None) -> list[dict]:
    """results.csv (every grid run so far, at its last iteration) and summary.json (the answers, of
    the finished runs only)."""
    rows = result_rows(out, spec, grid_cells(spec, chosen))
    store.write_csv(out / "results.csv", xr.RESULT_COLUMNS, rows)
    done = xr.finished(rows, spec.iterations)
    ctl = control_cell(spec)
    summary = {"runs": len(rows), "finished_runs": len(done),
               "answers": xr.answers(done, spec.dts, PROCESSES),
               "answers_deterministic": xr.answers(done, spec.dts, PROCESSES, key="det_reward_per_s"),
               "answers_auc": xr.answers(done, spec.dts, PROCESSES, key="auc_reward_per_s"),
               "chosen": {k: {"field": f, "value": v} for k, (f, v) in (chosen or {}).items()},
               "screen_from_grid": screen_from_grid(out, spec, chosen),
               "control": control_summary(out, spec, ctl, done) if ctl is not None else None,
               "commands": {f"{c.dt:g}/{c.process}": c.command(spec, out=f"runs/rerun/dt{c.dt:g}/{c.process}")
                            for c in grid_cells(spec, chosen)}}
    store.atomic_write_json(out / "summary.json", summary)
    return rows


def _snr(out: pathlib.Path, spec: StudySpec, chosen: dict, progress: bool) -> list[dict]:
    from nmrl.experiments import ppo_gradsnr
    from nmrl.learners.ppo import make_ppo

    path = out / "snr.csv"
    rows = store.read_csv(path) if path.exists() else []
    guard = signals.active()
    if guard is not None:
        guard.at("finishing")
    have = {(float(r["control_dt"]), r["exploration"], r["policy"]) for r in rows}
    for dt in spec.dts:
        cells = [grid_cell(spec, dt, p, chosen) for p in PROCESSES]
        mids = [c.dir(out) / "points" / "s0" / "mid" for c in cells]
        if not all(checkpoint.has_compact(m) for m in mids):
            continue
        for c, mid in zip(cells, mids):  # a cell's two policies side by side, one per device
            cfg = dataclasses.replace(c.sweep_spec(spec).base, seed=0)
            todo = [p for p in ("initial", "mid") if (dt, c.process, p) not in have]
            if not todo:
                continue
            t0 = time.time()
            states = [ppo_gradsnr.initial_state(cfg, 0) if policy == "initial"
                      else checkpoint.restore_compact(mid, make_ppo(cfg.resolved())) for policy in todo]
            measured = ppo_gradsnr.measure_many(cfg, states, batches=spec.snr_batches, seed=1)
            for policy, st, r in zip(todo, states, measured):
                rows.append({"control_dt": dt, "exploration": c.process, "setting": setting_label(c),
                             "policy": policy, "step": int(st.step), "estimates": r["periods"],
                             "batches": r["batches"], "seconds_per_estimate": r["seconds_per_estimate"],
                             **{k: r[k] for k in ("trcov", "trcov_ci", "mean_sq", "mean_sq_ci", "snr_per_s")}})
                if progress:
                    print(f"[snr dt={dt:g} {c.process} {policy}] snr per s {r['snr_per_s']:.3e} "
                          f"({time.time() - t0:,.0f} s with {', '.join(todo)})", file=sys.stderr, flush=True)
            store.write_csv(path, SNR_COLUMNS, rows)
            _stop_if_signalled(guard, f"the SNR of {c.process} at {dt:g} s")
    return rows


def _stop_if_signalled(guard: "signals.Guard | None", done: str) -> None:
    """After a measurement is written: a SIGINT/SIGTERM that came meanwhile stops the study here
    (:class:`nmrl.runs.signals.Interrupted`), with one line naming what was saved last, so a stop waits
    for one cell's measurement, not a whole control step's."""
    if guard is None or guard.signal is None:
        return
    print(f"nmrl explore-study: stopped by signal {guard.signal} after {done} was written; run the same "
          f"command again to continue", file=sys.stderr, flush=True)
    guard.raise_if_stopped()


def seed_from(published: pathlib.Path, out: pathlib.Path) -> list[pathlib.Path]:
    """Copy every published cell (sweep.json; per point config, metrics, compact state, mid-training
    state, evaluation) into ``out`` where ``out`` holds no sweep of that cell yet; returns them."""
    seeded = []
    for spec_file in sorted(published.glob("*/dt*/*/" + sweep.SPEC_FILE)):
        src = spec_file.parent
        dst = out / src.relative_to(published)
        if (dst / sweep.SPEC_FILE).exists():
            continue
        for f in src.rglob("*"):
            if f.is_file() and (f.name in ("sweep.json", "config.json", "metrics.jsonl", "compact.npz",
                                           "eval.json")):
                (dst / f.relative_to(src)).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(f, dst / f.relative_to(src))
        seeded.append(dst)
    if (published / SPEC_FILE).exists() and not (out / SPEC_FILE).exists():
        out.mkdir(parents=True, exist_ok=True)
        shutil.copy2(published / SPEC_FILE, out / SPEC_FILE)
    return seeded


def run_study(spec: StudySpec, out: str | pathlib.Path, *, phases: Sequence[str] = PHASES,
              published: str | pathlib.Path | None = None, progress: bool = True) -> list[dict]:
    """Run (or continue) the study into ``out`` (module docstring); returns results.csv's rows."""
    spec.validate()
    out = command.study_dir(out, phases, PHASES, StudyError)
    if published is not None and not pathlib.Path(published).is_dir():
        raise ValueError(f"--published={str(published)!r} is invalid: not a directory")
    out.mkdir(parents=True, exist_ok=True)
    held = lock.hold(out)
    try:
        if published is not None:
            for d in seed_from(pathlib.Path(published), out):
                if progress:
                    print(f"seeded {d} from the published compact states", file=sys.stderr, flush=True)
        _check_spec(out, spec)
        return _run(spec, out, phases, progress)
    finally:
        held.release(remove_if_empty=True)


def _grid_step(out: pathlib.Path, cell: Cell, spec: StudySpec, phases: Sequence[str], progress: bool) -> None:
    if "grid" in phases:
        run_cell(out, cell, spec, iterations=cell.iterations // 2, progress=progress)
        keep_mid(out, cell, spec)
        run_cell(out, cell, spec, progress=progress)
    if "eval" in phases:
        evaluate_points(out, cell, spec, progress)


def _run(spec: StudySpec, out: pathlib.Path, phases: Sequence[str], progress: bool) -> list[dict]:
    first = grid_cell(spec, spec.dts[0], "white", {})
    _grid_step(out, first, spec, phases, progress)
    write_results(out, spec, None)
    if "screen" in phases:
        for c in screen_cells(spec):
            run_cell(out, c, spec, progress=progress)
    chosen = chosen_settings(out, spec)
    if chosen is None:
        if progress:
            print("the screen has not finished: the grid's correlated processes wait for it", file=sys.stderr)
        return write_results(out, spec, None)
    for dt in spec.dts:  # the stages: a control step's SNR as soon as its cells have their mid states
        for c in [c for c in grid_cells(spec, chosen) if c.dt == dt]:
            _grid_step(out, c, spec, phases, progress)
            write_results(out, spec, chosen)
        if "snr" in phases:
            _snr(out, spec, chosen, progress)
    ctl = control_cell(spec)
    if ctl is not None:
        if "control" in phases:
            run_cell(out, ctl, spec, progress=progress)
        if "eval" in phases:
            evaluate_points(out, ctl, spec, progress)
    return write_results(out, spec, chosen)


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser.OneLineParser(prog="nmrl explore-study", description=__doc__.split("\n\n")[0])
    d = StudySpec()
    ap.add_argument("--out", required=True, help="study directory (continued if it exists)")
    ap.add_argument("--published", default=None,
                    help="a published copy of the study (results/exploration/runs): cells missing in --out "
                         "start from its compact states")
    ap.add_argument("--dt", type=float, nargs="+", default=list(d.dts), help="control steps [s], in run order")
    ap.add_argument("--seeds", type=int, default=d.seeds)
    ap.add_argument("--iterations", type=int, default=d.iterations, help="PPO iterations per grid run")
    ap.add_argument("--screen-dt", type=float, default=d.screen_dt)
    ap.add_argument("--screen-seeds", type=int, default=d.screen_seeds)
    ap.add_argument("--screen-iterations", type=int, default=d.screen_iterations)
    ap.add_argument("--num-envs", type=int, default=d.num_envs)
    ap.add_argument("--value-layers", type=int, default=d.value_layers)
    ap.add_argument("--value-width", type=int, default=d.value_width)
    ap.add_argument("--batch-size", type=int, default=d.batch_size, help="unrolls per minibatch")
    ap.add_argument("--num-minibatches", type=int, default=d.num_minibatches)
    ap.add_argument("--epochs", type=int, default=d.epochs)
    ap.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every)
    ap.add_argument("--eval-seconds", type=float, default=d.eval_seconds)
    ap.add_argument("--snr-batches", type=int, default=d.snr_batches)
    ap.add_argument("--physics", default=d.physics, help=PHYSICS_HELP)
    ap.add_argument("--env", default=d.env, help="every run's environment: paper-cheetah, halfcheetah-v5, hopper-v5, "
                                                 "walker2d-v5 (docs/tasks.md)")
    ap.add_argument("--phases", nargs="+", default=list(PHASES), help=f"any of {list(PHASES)}")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)

    def body() -> None:
        spec = StudySpec(env=a.env, physics=a.physics, dts=tuple(a.dt), seeds=a.seeds, iterations=a.iterations, screen_dt=a.screen_dt,
                         screen_seeds=a.screen_seeds, screen_iterations=a.screen_iterations, num_envs=a.num_envs,
                         value_layers=a.value_layers, value_width=a.value_width, batch_size=a.batch_size,
                         num_minibatches=a.num_minibatches, epochs=a.epochs, checkpoint_every=a.checkpoint_every,
                         eval_seconds=a.eval_seconds, snr_batches=a.snr_batches)
        run_study(spec, a.out, phases=a.phases, published=a.published, progress=not a.quiet)

    return command.run("nmrl explore-study", body, (StudyError, sweep.SweepError))


if __name__ == "__main__":
    sys.exit(main())
