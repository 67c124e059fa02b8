"""How a session's points sit on the devices: one run split over them, or many runs as one program.

A :class:`Point` is one run of the session (its directory, config, trainer and starting state);
:func:`begin_fresh` and :func:`begin_resumed` write what it starts with, once every check has
passed. Two layouts hold the points' states on the devices for the chunk loop
(nmrl/runs/loop.py), each compiling the chunk, running it for the active points and handing out
the states to checkpoint and the counters the loop decides by (several processes: gathered), and
saying where the points are (``banner``, the session's first line; ``chunk_name``, its compile line):

* :class:`OneRun` (``nmrl train``): one run, its N environments split over the local devices
  (:func:`num_shards`; ``psum``-ed updates, nmrl/runs/sharding.py), of every process in a
  multi-process run;
* :class:`Points` (a sweep or study): P runs stacked as one compiled program over the devices,
  one at a time (or a vmapped group) per device (nmrl/runs/points.py).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners
from nmrl.learners.contract import Config
from nmrl.runs import distributed as dist, sharding, store
from nmrl.runs import points as pts
from nmrl.runs.errors import RunError
from nmrl.runs.loop import compile_chunk
from nmrl.runs.store import to_python, truncate_metrics

Trainer = learners.Trainer


def _train_devices(cfg: Config, devices: int | None = None) -> list:
    """The devices the environment batch is split over: ``devices`` per process (default: all local
    devices). One process lowers the count to the largest that divides N; several processes
    (nmrl/runs/distributed.py) use the same count on each and need N to be a multiple of the total."""
    avail = len(jax.local_devices())
    if devices is not None and not (isinstance(devices, int) and 1 <= devices <= avail):
        raise RunError(f"devices={devices!r} is invalid: this process has {avail} local device(s)")
    n = avail if devices is None else devices
    if not dist.active():
        while cfg.budget.num_envs % n:
            n -= 1
        return jax.local_devices()[:n]
    devs = sharding.process_devices(n)
    if cfg.budget.num_envs % len(devs):
        raise RunError(f"num_envs={cfg.budget.num_envs} is invalid for {jax.process_count()} processes with {n} "
                       f"device(s) each: the environments are split over all {len(devs)} devices, so N must be a multiple "
                       f"of {len(devs)}")
    return devs


def num_shards(cfg: Config, devices: int | None = None) -> int:
    """How many devices (of every process) the environment batch is split over (:func:`_train_devices`)."""
    return len(_train_devices(cfg, devices))


def _sharded_trainer(cfg: Config, trainer, devices: int | None = None):
    n = num_shards(cfg, devices)
    if n == 1:
        return trainer
    return learners.of(cfg).make(cfg, env=trainer.env, axis_name=sharding.AXIS, num_shards=n)


@dataclasses.dataclass
class Point:
    """One run of this session: its directory, config (with this session's budget), trainer, the
    state it starts from, and whether it is frozen (diverged before this session)."""

    name: str
    dir: pathlib.Path
    cfg: Config
    trainer: Trainer
    ts: object
    frozen: bool = False
    record: dict | None = None  #: the resume record (None for a fresh start)


def begin_fresh(p: Point) -> None:
    """Write a fresh point's config.json and drop metrics of an earlier, unsaved start."""
    store.write_config(p.dir, p.cfg)
    store.remove_metrics(p.dir)


def begin_resumed(p: Point) -> None:
    """What a resume writes, after every point's checks passed: the metrics after the restored step
    are dropped (not for a frozen point: its last rows say why it stopped), a changed budget is
    written to config.json, and the resume is recorded in resumes.jsonl."""
    if not p.frozen:
        truncate_metrics(p.dir, p.record["from_step"])
    if p.record["config_json_updated"]:
        store.write_config(p.dir, p.cfg)
    store.append_resume(p.dir, p.record)


class OneRun:
    """Layout of :func:`~nmrl.runs.driver.train`: one point, its environments split over ``n_dev``
    devices (of every process in a multi-process run)."""

    def __init__(self, p: Point, devices: int | None):
        devs = _train_devices(p.cfg, devices)
        self.n_dev = n_dev = len(devs)
        trainer = _sharded_trainer(p.cfg, p.trainer, devices)
        if n_dev > 1:
            program, self.place = sharding.shard_train_chunk(trainer.chunk, p.ts, sharding.make_mesh(devs),
                                                             learners.of(p.cfg).env_fields)
        else:
            program, self.place = trainer.chunk, jax.device_put
        self.ts = self.place(p.ts)  # committed inputs: no second, hidden compile of the chunk
        self.program = program
        self.cfg = p.cfg
        #: the chunk as the line giving its compile time names it
        self.chunk_name = f"the training chunk ({p.cfg.budget.num_envs} environments on {n_dev} device(s))"

    def banner(self) -> str:
        """The line saying where the run's environments are."""
        n, n_dev = self.cfg.budget.num_envs, self.n_dev
        procs = f", {jax.process_count()} processes" if dist.active() else ""
        return (f"train: {n} environments on {n_dev} device(s), {n // n_dev} per device "
                f"({len(jax.local_devices())} local {jax.local_devices()[0].platform} device(s){procs})")

    def compile(self) -> float:
        self.chunk, compile_s = compile_chunk(self.program, self.ts)
        return compile_s

    def run(self, active: np.ndarray) -> list[dict | None]:
        ts_new, m = self.chunk(self.ts)
        m = to_python(dist.host(m))
        self.ts = self.place(ts_new)
        return [m]

    def state(self, i: int):
        """The state to checkpoint (several processes: gathered to the host, a collective)."""
        return dist.host(self.ts) if dist.active() else self.ts

    def counters(self) -> list[tuple[int, int, bool]]:
        """(step, trials, diverged) of the one point (several processes: a gather)."""
        step, trials, div = dist.host((self.ts.step, self.ts.trials, self.ts.diverged))
        return [(int(step), int(trials), bool(div))]


class Points:
    """Layout of :func:`~nmrl.runs.driver.run_points`: the stacked points over ``n_dev`` devices
    (nmrl/runs/points.py)."""

    def __init__(self, ps: Sequence[Point], n_dev: int, group: int, order: Sequence[int],
                 devices: Sequence | None = None):
        self.n_dev, self.devices = n_dev, devices
        self.slots = pts.slot_order(len(ps), n_dev, order)
        self.slot_of = {i: j for j, i in enumerate(self.slots) if i >= 0}
        self.ts = self._place(pts.stack_trees([ps[i if i >= 0 else 0].ts for i in self.slots]))
        self.program = pts.points_program(ps[0].trainer.chunk, n_dev, group, devices=devices)
        self.per_dev = len(self.slots) // n_dev
        self._host = None  # the host copy of the states gathered for this chunk's saves (several processes)
        self.num_points, self.group, self.num_envs = len(ps), group, ps[0].cfg.budget.num_envs
        #: the chunk as the line giving its compile time names it
        self.chunk_name = "the sweep chunk"

    def banner(self) -> str:
        """The line saying where the points are and how each device steps them."""
        n, group = self.num_envs, self.group
        return (f"sweep: {self.num_points} points x {n} environments on {self.n_dev} "
                f"{jax.local_devices()[0].platform} device(s), {self.per_dev} point(s) per device stepped "
                f"{'one at a time' if group == 1 else f'in vmapped groups of {group}'} "
                f"({n * min(group, self.per_dev)} environments per device at a time)")

    def _place(self, tree):
        return pts.place_points(tree, self.n_dev, devices=self.devices)

    def compile(self) -> float:
        t0 = time.time()
        active_like = self._place(np.zeros(len(self.slots), bool))
        self.chunk = jax.jit(self.program, donate_argnums=0).lower(self.ts, active_like).compile()
        return time.time() - t0

    def run(self, active: np.ndarray) -> list[dict | None]:
        act_slots = np.array([i >= 0 and active[i] for i in self.slots])
        self.ts, m = self.chunk(self.ts, self._place(jnp.asarray(act_slots)))
        self._host = None
        m = dist.host(m)
        return [to_python({k: v[self.slot_of[i]] for k, v in m.items()}) if a else None
                for i, a in enumerate(active)]

    def state(self, i: int):
        """Point ``i``'s state (several processes: from one host copy of every point per chunk,
        gathered at the first save -- a collective every process makes at the same save)."""
        if not dist.active():
            return pts.unstack(self.ts, self.slot_of[i])
        if self._host is None:
            self._host = dist.host(self.ts)
        return pts.unstack(self._host, self.slot_of[i])

    def counters(self) -> list[tuple[int, int, bool]]:
        """(step, trials, diverged) of every point, in point order (several processes: one gather)."""
        step, trials, div = dist.host((self.ts.step, self.ts.trials, self.ts.diverged))
        return [(int(step[j]), int(trials[j]), bool(div[j])) for _, j in sorted(self.slot_of.items())]
