"""The sweep over the period length l (and seeds) as one program: the paper's Fig. 3.

Every (l, seed) point is one training state; the states are stacked and ``jax.vmap`` runs the
learner's chunk on all of them in one jitted program. l lives in the traced ``Hyper`` pytree
(nmrl/learner.py): the in-period index is a counter compared with l, so no padding is needed and no
point recompiles. With several local devices (e.g. ``XLA_FLAGS=--xla_force_host_platform_device_count=2``
on a 2-core CPU) the points are split over them with ``shard_map`` (results then differ from a
1-device run in the last float bits). The vmapped chunk gives, point by point, the results of separate ``nmrl train``
runs: bit-identical with the small networks of tests/test_sweep.py, and equal up to float rounding
at the paper's sizes (largest parameter difference 2.4e-7 after 320 steps, benchmarks/bench_sweep.py),
where XLA batches the matrix products differently.

Layout of ``OUT``::

    sweep.json                       the sweep's spec (l values, seeds, base config)
    points/l{l}_s{seed}/             a complete run directory per point (config.json,
                                     metrics.jsonl, checkpoints/): ``nmrl eval`` and
                                     ``nmrl train --resume`` work on it
    results.csv                      l, seed, trials, steps, avg_reward, forward_speed, diverged, checkpoint
    fig3.png                         Fig. 3 and the learning curves (nmrl/plots.py)

``avg_reward`` in results.csv is the average reward per control step during learning (the
exploring policy, as the paper measures it), averaged over the last tenth of the chunks. A
diverged point is frozen at its last good parameters and marked; it never stops the sweep.
Resuming restores every point from the newest checkpoint step that all live points have; a
diverged point stays frozen at its last good checkpoint and keeps its metrics.
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

from nmrl import checkpoint, run, sharding
from nmrl.learner import Hyper, TrainConfig, make_train

SPEC_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
RESULT_COLUMNS = ("l", "seed", "trials", "steps", "avg_reward", "forward_speed", "diverged", "checkpoint")


class SweepError(Exception):
    """The sweep cannot start or resume (message says why)."""


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    ls: tuple[int, ...]
    seeds: int
    base: TrainConfig = TrainConfig()

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
        for cfg in self.point_configs():
            cfg.validate()

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


def run_points(out: str | os.PathLike, names: Sequence[str], configs: Sequence[TrainConfig], *,
               resume: bool = False, progress: bool = True, keep: int = 2, max_chunks: int | None = None,
               checkpoint_every: int = 1, on_chunk: Callable[[], None] | None = None,
               table: bool = True) -> None:
    """Train every config as one vmapped program; point ``names[i]`` lives in ``out/points/<name>/``.

    The configs may differ only in the traced :class:`Hyper` fields and the seed (one program).
    Every point is checkpointed every ``checkpoint_every`` chunks and when it finishes. ``resume``
    continues from the newest step all live points have (their later metrics rows are dropped); a
    diverged point stays frozen at its last good checkpoint. ``on_chunk()`` runs after every chunk;
    ``progress`` prints the compile time and (with ``table``) every point's latest metrics.
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
    trainers = [make_train(configs[0])]
    trainers += [make_train(c, env=trainers[0].env) for c in configs[1:]]
    dirs = [out / "points" / n for n in names]

    frozen = np.zeros(len(names), bool)
    if resume:
        steps = [run.existing_step(d) for d in dirs]
        if any(st is None for st in steps):
            raise SweepError(f"--resume: some points of {out} have no checkpoint; start a new sweep")
        # A diverged point stopped saving at its last good step and stays frozen there: it must not
        # pull the common resume step (and everybody's metrics) back to that step.
        frozen = np.array([any(run.is_diverged(r) for r in run.read_metrics(d)) for d in dirs])
        live = [st for st, f in zip(steps, frozen) if not f]
        common = min(live) if live else None
        states = []
        for d, tr, st, f in zip(dirs, trainers, steps, frozen):
            if f:
                states.append(checkpoint.restore(d, tr, step=st))
                continue
            if common not in checkpoint.all_steps(d):
                raise SweepError(f"--resume: {d} lacks the checkpoint of step {common} shared by all points")
            states.append(checkpoint.restore(d, tr, step=common))
            run.truncate_metrics(d, common)
    else:
        init = jax.jit(jax.vmap(trainers[0].init))
        keys = jnp.stack([jax.random.PRNGKey(c.seed) for c in configs])
        hypers = stack_trees([Hyper.from_config(c) for c in configs])
        ts = init(keys, hypers)
        states = [_unstack(ts, i) for i in range(len(names))]
        for d, c in zip(dirs, configs):
            d.mkdir(parents=True, exist_ok=True)
            run.atomic_write_text(d / run.CONFIG_FILE, json.dumps(dataclasses.asdict(c), indent=2) + "\n")
            (d / run.METRICS_FILE).unlink(missing_ok=True)
    P = len(names)
    # Points are independent: split them over the local devices (no communication at all).
    n_dev = len(jax.local_devices())
    if n_dev > 1 and P % n_dev == 0:
        mesh = sharding.make_mesh()
        place = lambda t: sharding.shard_batch(t, mesh)  # noqa: E731
        program = sharding.shard_map_batch(jax.vmap(trainers[0].chunk), mesh, jit=False)
    else:
        n_dev = 1
        place = jax.device_put
        program = jax.vmap(trainers[0].chunk)
    ts = place(stack_trees(states))
    chunk, compile_s = run.compile_chunk(program, ts, donate=False)
    if progress:
        print(f"compiled the sweep chunk ({P} points on {n_dev} device(s)) in {compile_s:.1f} s",
              file=sys.stderr, flush=True)

    active = np.array([not run.budget_done(c, int(ts.step[i]), int(ts.trials[i])) and not bool(ts.diverged[i])
                       and not frozen[i] for i, c in enumerate(configs)])
    last_rows: dict = {}
    t_start = time.time()
    n_chunks = 0
    while active.any():
        t0 = time.time()
        new_ts, m = chunk(ts)
        m = jax.device_get(m)
        wall = time.time() - t0
        act = jnp.asarray(active)
        ts = place(jax.tree.map(lambda n, o: jnp.where(act.reshape((-1,) + (1,) * (n.ndim - 1)), n, o),
                                new_ts, ts))
        for i, (name, d, c) in enumerate(zip(names, dirs, configs)):
            if not active[i]:
                continue
            row = run.metrics_row(c, run.to_python({k: v[i] for k, v in m.items()}), wall, points=P)
            run.append_metrics(d, row)
            last_rows[name] = row
            if run.is_diverged(row):
                active[i] = False  # keep its last good checkpoint; frozen from now on
                continue
            finished = run.budget_done(c, row["step"], row["trials"])
            if finished or (n_chunks + 1) % checkpoint_every == 0:
                checkpoint.save(d, _unstack(ts, i), c, keep=keep)
            if finished:
                active[i] = False
        if on_chunk is not None:
            on_chunk()
        if progress and table:
            print(_progress_table(names, last_rows, time.time() - t_start), file=sys.stderr, flush=True)
        n_chunks += 1
        if max_chunks is not None and n_chunks >= max_chunks:
            break


def run_sweep(spec: SweepSpec, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
              keep: int = 2, max_chunks: int | None = None, plot: bool = True,
              checkpoint_every: int = 1) -> list[dict]:
    """Run (or resume) the sweep into ``out`` (:func:`run_points`); returns the results rows."""
    spec.validate()
    out = pathlib.Path(out)
    if resume:
        if not (out / SPEC_FILE).exists():
            raise SweepError(f"--resume: {out / SPEC_FILE} not found; is {out} a sweep directory?")
        saved = json.loads((out / SPEC_FILE).read_text())
        base = TrainConfig(**saved["base"])
        if spec.base.steps is not None or spec.base.trials is not None:  # the budget may be extended
            base = dataclasses.replace(base, steps=spec.base.steps, trials=spec.base.trials)
        spec = SweepSpec(ls=tuple(saved["ls"]), seeds=saved["seeds"], base=base)
        spec.validate()
    elif (out / SPEC_FILE).exists():
        raise SweepError(f"{out} already holds a sweep; continue it with --resume or choose another --out")
    base = spec.base.resolved()
    spec = dataclasses.replace(spec, base=base)
    if not resume:
        out.mkdir(parents=True, exist_ok=True)
        run.atomic_write_text(out / SPEC_FILE, json.dumps(
            {"ls": list(spec.ls), "seeds": spec.seeds, "base": dataclasses.asdict(base)}, indent=2) + "\n")

    def on_chunk():
        results = write_results(out, spec)
        if plot:
            from nmrl import plots

            plots.fig3(out, results)

    names = [point_dir(out, l, s).name for l, s in spec.points()]
    run_points(out, names, spec.point_configs(), resume=resume, progress=progress, keep=keep,
               max_chunks=max_chunks, checkpoint_every=checkpoint_every, on_chunk=on_chunk)
    return write_results(out, spec)


def load_results(out: str | os.PathLike) -> list[dict]:
    with open(pathlib.Path(out) / RESULTS_FILE) as f:
        return list(csv.DictReader(f))


__all__: Sequence[str] = ("SweepSpec", "SweepError", "run_sweep", "run_points", "load_results", "point_dir", "final_avg")
