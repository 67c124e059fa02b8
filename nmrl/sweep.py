"""The sweep over the period length l (and seeds) as one program: the paper's Fig. 3 (Sec. V-D).

Every (l, seed) point is one training state; the states are stacked and one jitted program runs
the learner's chunk on all of them. l lives in the traced ``Hyper`` pytree (nmrl/learner.py): the
in-period index is a counter compared with l, so no padding is needed and no point recompiles.

Layout (:func:`points_program`, chosen by measurement in benchmarks/bench_sweep.py): MJX's cost per
environment step on a CPU grows with the batch one device holds, so the points are split over the
local devices with ``shard_map`` (no communication; on a CPU nmrl.devices exposes one device per
core) and each device steps its points one after another (``lax.map``; ``group`` > 1 vmaps that many
together). A point that is not active (finished, diverged, or waiting for the ``first`` stage) is
skipped by ``lax.cond``. Every point gives the results of a separate ``nmrl train`` run up to float
rounding (the two programs are compiled apart; tests/test_sweep.py).

Layout of ``OUT``::

    sweep.json                       the sweep's spec (l values, seeds, base config)
    points/l{l}_s{seed}/             a complete run directory per point (config.json,
                                     metrics.jsonl, checkpoints/, compact.npz): ``nmrl eval``
                                     and ``nmrl train --resume`` work on it
    results.csv                      l, seed, trials, steps, avg_reward, forward_speed, diverged, checkpoint
    fig3.png                         Fig. 3 and the learning curves (nmrl/plots.py)

``avg_reward`` in results.csv is the average reward per control step during learning (the
exploring policy, as the paper measures it), averaged over the last tenth of the chunks. A
diverged point is frozen at its last good parameters and marked; it never stops the sweep.
Resuming restores every point from its own newest full checkpoint, else from its compact
continuation state (``compact.npz``: parameters, counters, PRNG key; every environment then starts a
new trial, so the continuation is statistically, not bitwise, equal); a point of a later stage that
never ran starts as a fresh sweep would. A diverged point stays frozen at its last good checkpoint
and keeps its metrics.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import pathlib
import sys
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jax.sharding import PartitionSpec as P

from nmrl import checkpoint, run, sharding
from nmrl.learner import Hyper, TrainConfig, make_train

SPEC_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
#: fig3.png is redrawn after a chunk only when this many seconds passed since the last drawing
PLOT_EVERY_S = 120.0
RESULT_COLUMNS = ("l", "seed", "trials", "steps", "avg_reward", "forward_speed", "diverged", "checkpoint")


class SweepError(Exception):
    """The sweep cannot start or resume (message says why)."""


class Stopped(Exception):
    """The sweep was stopped by a signal after saving every active point (``signum``)."""

    def __init__(self, signum: int):
        super().__init__(f"stopped by signal {signum}")
        self.signum = signum


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    ls: tuple[int, ...]
    seeds: int
    base: TrainConfig = TrainConfig()
    #: l values whose points (every seed) run to the budget before the other points start
    first: tuple[int, ...] = ()

    def validate(self) -> None:
        if len(self.ls) == 0:
            raise ValueError("the list of l values is empty: give at least one, e.g. --l 1 10")
        for l in self.ls:
            if not isinstance(l, int) or isinstance(l, bool) or l < 1:
                raise ValueError(f"l={l!r} is invalid: every l must be an integer >= 1")
        dup = sorted({l for l in self.ls if self.ls.count(l) > 1})
        if dup:
            raise ValueError(f"duplicate l values {dup}: each l may appear once")
        if not isinstance(self.seeds, int) or isinstance(self.seeds, bool) or self.seeds < 1:
            raise ValueError(f"seeds={self.seeds!r} is invalid: must be an integer >= 1")
        bad = [l for l in self.first if l not in self.ls]
        if bad or len(set(self.first)) != len(self.first):
            raise ValueError(f"first={list(self.first)} is invalid: the l values that run first must be "
                             f"distinct values of the sweep's l list {list(self.ls)}")
        for cfg in self.point_configs():
            cfg.validate()

    def stages(self) -> list[list[int]] | None:
        """Point indices by stage: the points of ``first`` (every seed), then the rest."""
        if not self.first:
            return None
        pts = self.points()
        return [[i for i, (l, _) in enumerate(pts) if l in self.first]]

    def points(self) -> list[tuple[int, int]]:
        return [(l, s) for l in self.ls for s in range(self.seeds)]

    def point_configs(self) -> list[TrainConfig]:
        return [dataclasses.replace(self.base, l=l, seed=s) for l, s in self.points()]


def point_dir(out: pathlib.Path, l: int, seed: int) -> pathlib.Path:
    return out / "points" / f"l{l}_s{seed}"


def stack_trees(trees):
    """Stack pytrees of equal structure along a new leading axis (one entry per point)."""
    return jax.tree.map(lambda *x: jnp.stack(x), *trees)


def _unstack(tree, i: int):
    return jax.tree.map(lambda x: x[i], tree)


def final_avg(rows: list[dict], key: str) -> float:
    """Mean of ``key`` over the last tenth (at least one) of the chunks."""
    if not rows:
        return float("nan")
    k = max(1, len(rows) // 10)
    return float(np.mean([r[key] for r in rows[-k:]]))


def write_results(out: pathlib.Path, spec: SweepSpec) -> list[dict]:
    """(Re)write results.csv atomically from the points' metrics; returns the rows."""
    rows = []
    for (l, s) in spec.points():
        d = point_dir(out, l, s)
        m = run.read_metrics(d)
        last = m[-1] if m else {}
        rows.append({
            "l": l, "seed": s, "trials": last.get("trials", 0), "steps": last.get("step", 0),
            "avg_reward": final_avg(m, "avg_reward"), "forward_speed": final_avg(m, "forward_speed"),
            "diverged": bool(any(r["diverged"] for r in m)),
            "checkpoint": os.path.relpath(d, out) if run.existing_step(d) is not None else "",
        })
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=RESULT_COLUMNS)
    w.writeheader()
    w.writerows(rows)
    run.atomic_write_text(out / RESULTS_FILE, buf.getvalue())
    return rows


HYPER_FIELDS = tuple(Hyper._fields)


def _program_key(cfg: TrainConfig) -> TrainConfig:
    """The part of a config that is compiled into the program (everything but Hyper and the seed)."""
    return dataclasses.replace(cfg, seed=0, **{k: getattr(TrainConfig(), k) for k in HYPER_FIELDS})


def _progress_table(names: Sequence[str], rows_by_point: dict, elapsed: float) -> str:
    lines = [f"sweep: {len(names)} points, {elapsed:,.0f} s"]
    w = max(len(n) for n in names)
    for name in names:
        r = rows_by_point.get(name)
        if r is None:
            continue
        flag = "  DIVERGED" if r["diverged"] else ""
        lines.append(f"  {name:<{w}}  trials {r['trials']:>8,}  steps {r['step']:>8,}  "
                     f"avg reward {r['avg_reward']:+.3f}  speed {r['forward_speed']:+.2f} m/s{flag}")
    return "\n".join(lines)


def slot_order(num_points: int, num_devices: int, priority: Sequence[int] | None = None) -> list[int]:
    """Which point sits in which slot of the stacked state (slot j lives on device j // per_device).

    Points are dealt round-robin over the devices in ``priority`` order (default: their own order),
    so every prefix of the priority list (e.g. the paper's named points that run first) is spread
    evenly over the devices. The list is padded with ``-1`` (an idle slot) to a multiple of the devices.
    """
    order = list(range(num_points)) if priority is None else list(priority)
    if sorted(order) != list(range(num_points)):
        raise ValueError(f"priority {order} must be a permutation of range({num_points})")
    per = -(-num_points // num_devices)
    slots = [-1] * (per * num_devices)
    for rank, i in enumerate(order):
        slots[(rank % num_devices) * per + rank // num_devices] = i
    return slots


def points_program(chunk: Callable, num_devices: int, group: int = 1) -> Callable:
    """The sweep's layout: ``program(ts, active) -> (ts, metrics)`` for stacked point states.

    The points are split over ``num_devices`` devices with ``shard_map`` (no communication at all).
    Within a device the points are stepped one after another by ``lax.map`` (``group`` > 1: in vmapped
    groups of that many), so a device only ever works on one point's environments at a time: MJX's
    cost per environment step on a CPU grows with the batch one device holds (benchmarks/bench_sweep.py).
    A point whose ``active`` flag is False is skipped (``lax.cond``; with ``group`` > 1 it is computed
    and discarded) and comes back unchanged, with zero metrics.
    """
    if not (isinstance(group, int) and not isinstance(group, bool) and group >= 1):
        raise ValueError(f"group={group!r} is invalid: points vmapped together must be an integer >= 1")

    def per_device(ts, active):
        one_ts = jax.tree.map(lambda x: x[0], ts)
        m_shape = jax.eval_shape(chunk, one_ts)[1]

        def one(args):
            t, a = args
            return jax.lax.cond(a, chunk, lambda t: (t, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), m_shape)), t)

        return jax.lax.map(one, (ts, active), batch_size=None if group == 1 else group)

    if num_devices == 1:
        return per_device
    mesh = sharding.make_mesh(jax.local_devices()[:num_devices])
    return jax.shard_map(per_device, mesh=mesh, in_specs=(P(sharding.AXIS), P(sharding.AXIS)),
                         out_specs=P(sharding.AXIS), check_vma=False)


def _place_points(tree, num_devices: int):
    if num_devices == 1:
        return jax.device_put(tree, jax.local_devices()[0])
    return sharding.shard_batch(tree, sharding.make_mesh(jax.local_devices()[:num_devices]))


def run_points(out: str | os.PathLike, names: Sequence[str], configs: Sequence[TrainConfig], *,
               resume: bool = False, progress: bool = True, keep: int = 2, max_chunks: int | None = None,
               checkpoint_every: int = 1, on_chunk: Callable[[], None] | None = None,
               table: bool = True, priority: Sequence[int] | None = None, group: int = 1,
               devices: int | None = None) -> int | None:
    """Train every config as one compiled program; point ``names[i]`` lives in ``out/points/<name>/``.

    The configs may differ only in the traced :class:`Hyper` fields and the seed (one program).
    Layout (:func:`points_program`): the points are split over ``devices`` local devices (default:
    all), stepped one after another on each (``group`` points vmapped together). ``priority`` is a
    list of stages, each a list of point indices: a stage's points run only when every earlier
    stage's points have finished their budget or diverged (points named in no stage form a last
    stage); the points are dealt over the devices in that order (:func:`slot_order`).
    Every point is checkpointed every ``checkpoint_every`` chunks and when it finishes, and writes
    its compact continuation state (nmrl.checkpoint.save_compact) beside. ``resume`` continues every
    point from its newest checkpoint (its later metrics rows are dropped); a point without full
    checkpoints continues from its compact state (statistically, not bitwise, equal: every
    environment starts a new trial). A diverged point stays frozen at its last good checkpoint.
    ``on_chunk()`` runs after every chunk; ``progress`` prints the layout, the compile time and
    (with ``table``) every point's latest metrics. SIGINT/SIGTERM stop the sweep after the chunk in
    flight, with every active point checkpointed; the signal number is returned (None otherwise).
    """
    if not (isinstance(checkpoint_every, int) and checkpoint_every >= 1):
        raise ValueError(f"checkpoint_every={checkpoint_every!r} is invalid: must be an integer >= 1")
    if len(names) != len(configs) or len(set(names)) != len(names) or not names:
        raise ValueError(f"need one distinct name per config, got {len(names)} names for {len(configs)} configs")
    out = pathlib.Path(out)
    configs = [c.resolved() for c in configs]
    key0 = _program_key(configs[0])
    for n, c in zip(names, configs):
        if _program_key(c) != key0:
            diff = [f.name for f in dataclasses.fields(c) if getattr(_program_key(c), f.name) != getattr(key0, f.name)]
            raise ValueError(f"point {n!r} differs from {names[0]!r} in {diff}: one program can only vary "
                             f"{', '.join(HYPER_FIELDS)} and the seed")
    P_ = len(names)
    stages = _stages(priority, P_)
    n_avail = len(jax.local_devices())
    n_dev = n_avail if devices is None else devices
    if not (isinstance(n_dev, int) and 1 <= n_dev <= n_avail):
        raise ValueError(f"devices={devices!r} is invalid: this process has {n_avail} local device(s)")
    n_dev = min(n_dev, P_)
    trainers = [make_train(configs[0])]
    trainers += [make_train(c, env=trainers[0].env) for c in configs[1:]]
    dirs = [out / "points" / n for n in names]

    frozen = np.zeros(P_, bool)
    states: list = [None] * P_
    if resume:
        steps = [run.existing_step(d) for d in dirs]
        compact = [checkpoint.has_compact(d) for d in dirs]
        # a point of a later stage that never ran a chunk starts as a fresh sweep would start it
        fresh = [st is None and not c and not run.read_metrics(d) for d, st, c in zip(dirs, steps, compact)]
        missing = [n for n, st, c, f in zip(names, steps, compact, fresh) if st is None and not c and not f]
        if missing:
            raise SweepError(f"--resume: points {missing[:5]} of {out} have neither a checkpoint nor a "
                             f"compact state; start a new sweep")
        # A diverged point stopped saving at its last good step and stays frozen there: it must not
        # pull the common resume step (and everybody's metrics) back to that step.
        frozen = np.array([any(run.is_diverged(r) for r in run.read_metrics(d)) for d in dirs])
        # Every point continues from its own newest checkpoint (the points are independent: the
        # program steps each one alone, so a point's continuation does not depend on the others'
        # steps); its metrics rows after that step are dropped. A diverged point stays frozen.
        for i, (d, tr, st, f) in enumerate(zip(dirs, trainers, steps, frozen)):
            if fresh[i]:
                states[i] = jax.jit(tr.init)(jax.random.PRNGKey(tr.config.seed), Hyper.from_config(tr.config))
                _write_point_config(d, tr.config)
            elif st is None:  # no full checkpoint (e.g. a fresh clone of published results)
                states[i] = checkpoint.restore_compact(d, tr)
                run.truncate_metrics(d, int(states[i].step))
            else:
                states[i] = checkpoint.restore(d, tr, step=st)
                if not f:
                    run.truncate_metrics(d, st)
    else:
        init = jax.jit(jax.vmap(trainers[0].init))
        keys = jnp.stack([jax.random.PRNGKey(c.seed) for c in configs])
        hypers = stack_trees([Hyper.from_config(c) for c in configs])
        ts = init(keys, hypers)
        states = [_unstack(ts, i) for i in range(P_)]
        for d, c in zip(dirs, configs):
            _write_point_config(d, c)
            (d / run.METRICS_FILE).unlink(missing_ok=True)
    slots = slot_order(P_, n_dev, [i for st in stages for i in st])
    slot_of = {i: j for j, i in enumerate(slots) if i >= 0}
    ts = _place_points(stack_trees([states[i if i >= 0 else 0] for i in slots]), n_dev)
    del states
    program = points_program(trainers[0].chunk, n_dev, group)
    active_like = _place_points(jnp.zeros(len(slots), bool), n_dev)
    per_dev = len(slots) // n_dev
    if progress:
        print(f"sweep: {P_} points x {configs[0].num_envs} environments on {n_dev} "
              f"{jax.local_devices()[0].platform} device(s), {per_dev} point(s) per device stepped "
              f"{'one at a time' if group == 1 else f'in vmapped groups of {group}'} "
              f"({configs[0].num_envs * min(group, per_dev)} environments per device at a time)",
              file=sys.stderr, flush=True)
    t0 = time.time()
    chunk = jax.jit(program, donate_argnums=0).lower(ts, active_like).compile()
    compile_s = time.time() - t0
    if progress:
        print(f"compiled the sweep chunk in {compile_s:.1f} s", file=sys.stderr, flush=True)

    steps_now = np.asarray(jax.device_get(ts.step))
    trials_now = np.asarray(jax.device_get(ts.trials))
    div_now = np.asarray(jax.device_get(ts.diverged))
    done = np.array([run.budget_done(c, int(steps_now[slot_of[i]]), int(trials_now[slot_of[i]]))
                     or bool(div_now[slot_of[i]]) or frozen[i] for i, c in enumerate(configs)])
    last_rows: dict = {}
    t_start = time.time()
    n_chunks = 0
    unsaved: set[int] = set()  # points whose newest metrics row has no checkpoint yet

    def save(i: int) -> None:
        one = _unstack(ts, slot_of[i])
        checkpoint.save(dirs[i], one, configs[i], keep=keep)
        checkpoint.save_compact(dirs[i], one, configs[i])
        unsaved.discard(i)

    stop, restore_signals = run.stop_on_signals()
    try:
        while not done.all():
            stage = next(st for st in stages if not all(done[i] for i in st))
            active = np.zeros(P_, bool)
            active[[i for i in stage if not done[i]]] = True
            act_slots = np.array([i >= 0 and active[i] for i in slots])
            t0 = time.time()
            ts, m = chunk(ts, _place_points(jnp.asarray(act_slots), n_dev))
            m = jax.device_get(m)
            wall = time.time() - t0
            n_active = int(active.sum())
            for i, (name, d, c) in enumerate(zip(names, dirs, configs)):
                if not active[i]:
                    continue
                j = slot_of[i]
                row = run.metrics_row(c, run.to_python({k: v[j] for k, v in m.items()}), wall, points=n_active)
                run.append_metrics(d, row)
                last_rows[name] = row
                if run.is_diverged(row):
                    done[i] = True  # keep its last good checkpoint; frozen from now on
                    continue
                finished = run.budget_done(c, row["step"], row["trials"])
                if finished or (n_chunks + 1) % checkpoint_every == 0 or stop["signal"] is not None:
                    save(i)
                else:
                    unsaved.add(i)
                if finished:
                    done[i] = True
            if on_chunk is not None:
                on_chunk()
            if progress and table:
                print(_progress_table(names, last_rows, time.time() - t_start), file=sys.stderr, flush=True)
            n_chunks += 1
            if stop["signal"] is not None:
                for i in sorted(unsaved):  # the signal came after this chunk's saves
                    save(i)
                print(f"stopped by signal {stop['signal']} after saving every active point; continue with "
                      f"--resume", file=sys.stderr, flush=True)
                break
            if max_chunks is not None and n_chunks >= max_chunks:
                break
    finally:
        restore_signals()
    return stop["signal"]


def _write_point_config(d: pathlib.Path, cfg: TrainConfig) -> None:
    d.mkdir(parents=True, exist_ok=True)
    run.atomic_write_text(d / run.CONFIG_FILE, json.dumps(dataclasses.asdict(cfg), indent=2) + "\n")


def at_milestone(rows: list[dict], m: int) -> float | None:
    """Mean avg_reward of the chunks whose trial count lies in (0.9 m, m] (the last tenth before the
    milestone m); None when the run has not reached m trials."""
    if not rows or rows[-1]["trials"] < m:
        return None
    sel = [r["avg_reward"] for r in rows if 0.9 * m < r["trials"] <= m]
    if not sel:  # a chunk longer than a tenth of m: the last chunk at or before m
        before = [r for r in rows if r["trials"] <= m]
        sel = [before[-1]["avg_reward"]] if before else []
    return float(np.mean(sel)) if sel else None


def _stages(priority, num_points: int) -> list[list[int]]:
    """Stages of point indices: ``None`` = one stage with every point; a list of lists as given
    (points not named form a last stage)."""
    if priority is None:
        return [list(range(num_points))]
    stages = [list(st) for st in priority if len(st)]
    named = [i for st in stages for i in st]
    if len(set(named)) != len(named) or any(not (0 <= i < num_points) for i in named):
        raise ValueError(f"priority stages {stages} must name distinct point indices in range({num_points})")
    rest = [i for i in range(num_points) if i not in set(named)]
    return stages + ([rest] if rest else [])


def run_sweep(spec: SweepSpec, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
              keep: int = 2, max_chunks: int | None = None, plot: bool = True,
              checkpoint_every: int = 1, group: int = 1, devices: int | None = None,
              given: dict | None = None) -> list[dict]:
    """Run (or resume) the sweep into ``out`` (:func:`run_points`); returns the results rows.

    A resume continues the saved spec; ``given`` (the config options given on the command line)
    may change only the budget: any other that differs from the saved base config (e.g. another
    ``actor_opt`` chain) is refused (SweepError naming them), before anything is written."""
    spec.validate()
    out = pathlib.Path(out)
    if resume:
        if not (out / SPEC_FILE).exists():
            raise SweepError(f"--resume: {out / SPEC_FILE} not found; is {out} a sweep directory?")
        saved = json.loads((out / SPEC_FILE).read_text())
        base = TrainConfig(**saved["base"])
        if given:
            try:
                run._given_changes(base, given, out)
            except run.RunError as e:
                raise SweepError(str(e).replace("the run in", "the sweep in")) from e
        if spec.base.steps is not None or spec.base.trials is not None:  # the budget may be extended
            base = dataclasses.replace(base, steps=spec.base.steps, trials=spec.base.trials)
        spec = SweepSpec(ls=tuple(saved["ls"]), seeds=saved["seeds"], base=base,
                         first=tuple(saved.get("first", ())))
        spec.validate()
    elif (out / SPEC_FILE).exists():
        raise SweepError(f"{out} already holds a sweep; continue it with --resume or choose another --out")
    base = spec.base.resolved()
    spec = dataclasses.replace(spec, base=base)
    if not resume:
        out.mkdir(parents=True, exist_ok=True)
        run.atomic_write_text(out / SPEC_FILE, json.dumps(
            {"ls": list(spec.ls), "seeds": spec.seeds, "first": list(spec.first),
             "base": dataclasses.asdict(base)}, indent=2) + "\n")

    last_plot = [0.0]

    def on_chunk():
        results = write_results(out, spec)
        if plot and time.time() - last_plot[0] >= PLOT_EVERY_S:
            from nmrl import plots

            plots.fig3(out, results)
            last_plot[0] = time.time()

    names = [point_dir(out, l, s).name for l, s in spec.points()]
    try:
        signum = run_points(out, names, spec.point_configs(), resume=resume, progress=progress, keep=keep,
                            max_chunks=max_chunks, checkpoint_every=checkpoint_every, on_chunk=on_chunk,
                            priority=spec.stages(), group=group, devices=devices)
    finally:
        results = write_results(out, spec)
        if plot and (out / "points").is_dir():
            from nmrl import plots

            plots.fig3(out, results)
    if signum is not None:
        raise Stopped(signum)
    return results


def load_results(out: str | os.PathLike) -> list[dict]:
    with open(pathlib.Path(out) / RESULTS_FILE) as f:
        return list(csv.DictReader(f))


__all__: Sequence[str] = ("SweepSpec", "SweepError", "Stopped", "run_sweep", "run_points", "load_results", "point_dir", "final_avg")
