"""The chunk loop of every run, and what it decides, shows and stops on between two chunks.

Between two chunks of ``chunk_steps`` control steps (one ``jit``-compiled ``lax.scan``,
:func:`compile_chunk`) the loop (:func:`drive`) only appends one metrics row per point to its
``metrics.jsonl`` (:func:`metrics_row`), checkpoints the points (one
:class:`~nmrl.runs.checkpoint.Checkpointer` per point, saving every ``checkpoint_every`` chunks,
when a point finishes its budget (:func:`budget_done`) and when a signal stops the loop) and shows
progress (:class:`Progress`, :func:`progress_table`). It runs the points as a layout
(nmrl/runs/layout.py) holds them.

Several processes (nmrl/runs/distributed.py) run the loop in lockstep: each chunk starts at a
barrier, after it they agree on the signal and on process 0's checkpoint decisions, and only
process 0 writes.

SIGINT/SIGTERM at any moment go through one :class:`nmrl.runs.signals.Guard` (:func:`guarded`: the
command's, else one of the caller's own): during the compile the run stops when the compile
returns, before anything of it is written (:func:`compile_or_stop`); during the chunk loop after
the chunk in flight, every active point saved (:class:`Stopped`), or, when the chunk is still
computing at the end of the supervisor's grace, at once with the last saved chunk kept
(:meth:`nmrl.runs.signals.Guard.chunk`); a second signal stops at once
(the last checkpoints are intact because checkpoints are written atomically). A loop of another
kind (the Brax PPO baseline) takes the same guard and stops after its iteration's save.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
import weakref
from typing import Callable, Iterator, Sequence

import jax
import numpy as np

from nmrl import learners
from nmrl.learners.contract import Config
from nmrl.runs import checkpoint, distributed as dist, signals
from nmrl.runs.errors import Diverged, Stopped
from nmrl.runs.preflight import allocate
from nmrl.runs.store import append_metrics, is_diverged



def _compile_needed(guard: signals.Guard) -> bool:
    """Whether to compile the chunk: not when one process was already stopped by a signal (it stops
    at once, before anything of the run is written, instead of after a compile of tens of seconds);
    several processes compile and then agree on the signal (nmrl/runs/distributed.py)."""
    return guard.signal is None or dist.active()


def compile_chunk(fn, ts, donate: bool = True):
    """AOT-compile ``fn`` (donating its argument if ``donate``) for ``ts``; returns (compiled, seconds)."""
    t0 = time.time()
    compiled = jax.jit(fn, donate_argnums=0 if donate else ()).lower(ts).compile()
    return compiled, time.time() - t0


@contextlib.contextmanager
def guarded() -> Iterator[signals.Guard]:
    """The signal guard for the block: the command's (a command installs one for its whole life),
    else one installed here (a library call) and restored when the block ends."""
    guard = signals.active()
    own_guard = guard is None
    if own_guard:
        guard = signals.Guard().install()
    try:
        yield guard
    finally:
        if own_guard:
            guard.restore()


def compile_or_stop(guard: signals.Guard, layout, cfg: Config, *, chunk: str | None, stopped: str,
                    step: int) -> None:
    """Compile the ``layout``'s chunk (not when a signal already stopped this one process), then
    stop if a signal came to any process: before the first chunk nothing of this session is
    written, so :class:`Stopped` (at ``step``, no rows) follows one line ending with ``stopped``
    (what is left, how to continue). ``chunk`` names the chunk in the line giving the compile time
    (None: no line)."""
    guard.at("compiling")
    if _compile_needed(guard):
        compile_s = allocate(layout.compile, "compiling the chunk", cfg)
        if chunk is not None:
            print(f"compiled {chunk} in {compile_s:.1f} s", file=sys.stderr, flush=True)
    signum, _ = _agreed(guard.signal, np.zeros(0, bool), "compiled")
    if signum is not None:  # stopped before the first chunk: nothing of this session is written
        print(f"stopped by signal {signum} before the first chunk; {stopped}", file=sys.stderr, flush=True)
        raise Stopped(signum, step, [])
    guard.at("starting")


def metrics_row(cfg: Config, m: dict, wall: float, points: int = 1) -> dict:
    """One metrics.jsonl object from a chunk's metrics (``points`` programs shared the wall time).

    ``return_per_trial`` is the chunk's reward over the trials (episodes) that ended in it, None
    without one: by the renewal-reward theorem the mean episode return of a policy that stays put,
    what a Gymnasium user reads as the return; biased while the policy moves within a chunk and when
    a chunk ends few trials."""
    trials = int(m.get("trials_in_chunk", 0))
    total = float(m["avg_reward"]) * cfg.budget.chunk_steps * cfg.budget.num_envs
    return {"chunk": m["step"] // cfg.budget.chunk_steps, **m, "total_steps": m["step"] * cfg.budget.num_envs,
            "wall_s": wall, "steps_per_s": points * cfg.budget.chunk_steps * cfg.budget.num_envs / wall,
            "return_per_trial": total / trials if trials > 0 else None}


def budget_done(cfg: Config, ts_step: int, ts_trials: int) -> bool:
    if cfg.budget.steps is not None:
        return ts_step >= cfg.budget.steps
    return ts_trials >= cfg.budget.trials


def budget_text(cfg: Config) -> str:
    """The budget :func:`budget_done` checks, as the command line gives it: ``steps=N`` or ``trials=N``."""
    return f"steps={cfg.budget.steps}" if cfg.budget.steps is not None else f"trials={cfg.budget.trials}"


def next_save(step: int, chunk_steps: int, every: int, wall_s: float) -> str:
    """When the next checkpoint is due after a chunk that ended at ``step`` and took ``wall_s``
    seconds, saves falling at multiples of ``every`` chunks: what a supervisor's signal would keep
    (the progress line shows it)."""
    period = every * chunk_steps
    at = (step // period + 1) * period
    return f"next save at step {at:,} in ~{(at - step) // chunk_steps * wall_s:,.0f} s"


#: the least time between two lines of a chunk's heartbeat [s]
BEAT_S = 10.0
#: without a terminal, the longest time a chunk in flight goes without a line [s] (:class:`Progress`)
TICK_S = 30.0


class Progress:
    """A rich progress bar on a terminal, one plain line per chunk otherwise.

    ``done0`` is where this session started (a resumed run): the ETA extrapolates this session's
    own speed, not the run's whole progress over this session's time. Each line also says when the
    next checkpoint is due (a save every ``every`` chunks, :func:`next_save`). Without a terminal a
    chunk that runs longer than :data:`TICK_S` without a line (no heartbeat: a program without host
    callbacks, e.g. PPO on MJX, whose compile stays cacheable) gets one every :data:`TICK_S` s with
    its time so far and the last chunk's; on a terminal the bar's clock moves by itself.
    """

    def __init__(self, cfg: Config, enabled: bool, done0: int = 0, every: int = 1):
        self.cfg = cfg
        self.every = every
        self.enabled = enabled
        self.rich = enabled and sys.stderr.isatty()
        self.t0 = self.t_beat = self.t_chunk = self.t_line = time.time()
        self.last_chunk_s: float | None = None
        self._closed = threading.Event()
        if enabled and not sys.stderr.isatty():
            threading.Thread(target=type(self)._tick, args=(weakref.ref(self), self._closed), name="nmrl-progress",
                             daemon=True).start()
        self.total = cfg.budget.steps if cfg.budget.steps is not None else cfg.budget.trials
        self.frac0 = min(done0 / self.total, 1.0)
        if self.rich:
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(TextColumn("[bold]train[/]"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
                                TimeRemainingColumn(), TextColumn("{task.description}"), transient=False)
            self.task = self.bar.add_task("compiling…", total=self.total, completed=min(done0, self.total))
            self.bar.start()

    def eta(self, frac: float) -> float:
        """Seconds left at ``frac`` of the budget, from this session's speed (nan before any progress)."""
        gained = frac - self.frac0
        return (time.time() - self.t0) * (1 - frac) / gained if gained > 0 else float("nan")

    def update(self, row: dict) -> None:
        if not self.enabled:
            return
        cfg = self.cfg
        done = row["step"] if cfg.budget.steps is not None else row["trials"]
        of = f" of {cfg.budget.steps:,}" if cfg.budget.steps is not None else ""
        per = row.get("return_per_trial")
        ret = f", {per:+.1f}/trial" if per is not None else ""
        text = (f"trials {row['trials']:,}  step {row['step']:,}{of} per env ({row['total_steps']:,} in all, "
                f"{row['steps_per_s']:,.0f}/s)  reward {row['avg_reward']:+.3f}/step "
                f"({row['avg_reward'] / cfg.environment.control_dt:+.1f}/s{ret})  speed {row['forward_speed']:+.2f} m/s")
        if done < self.total and "wall_s" in row:  # the last chunk's save is the end
            text += f"  {next_save(row['step'], cfg.budget.chunk_steps, self.every, row['wall_s'])}"
        now = time.time()
        self.last_chunk_s, self.t_chunk, self.t_line = now - self.t_chunk, now, now
        if self.rich:
            self.bar.update(self.task, completed=min(done, self.total), description=text)
        else:
            frac = min(done / self.total, 1.0)
            print(f"[{100 * frac:5.1f}%] {text}  ETA {self.eta(frac):,.0f}s", file=sys.stderr, flush=True)

    @staticmethod
    def _tick(ref: "weakref.ref[Progress]", closed: threading.Event) -> None:
        """The plain line's clock (class docstring): a line when the chunk in flight has shown none
        for :data:`TICK_S` seconds; it ends with :meth:`close` or with the bar itself."""
        while not closed.wait(min(1.0, TICK_S)):
            bar = ref()
            if bar is None:
                return
            now = time.time()
            if now - bar.t_line >= TICK_S:
                bar.t_line = now
                last = f" (the last chunk took {bar.last_chunk_s:,.0f} s)" if bar.last_chunk_s is not None else ""
                print(f"  the chunk has run {now - bar.t_chunk:,.0f} s{last}", file=sys.stderr, flush=True)
            del bar

    def beat(self, stage: str, done: int, n: int) -> None:
        """Where the chunk in flight is (nmrl/learners/heartbeat.py: a PPO iteration's unrolls and
        epochs): a line at most every :data:`BEAT_S` seconds, so a chunk of minutes shows it moves."""
        now = time.time()
        if not self.enabled or now - self.t_beat < BEAT_S:
            return
        self.t_beat = self.t_line = now
        text = f"in the chunk: {stage} {done}/{n} ({'unrolls' if stage == 'rollout' else 'epochs'})"
        if self.rich:
            self.bar.update(self.task, description=text)
        else:
            print(f"  {text}", file=sys.stderr, flush=True)

    def close(self) -> None:
        self._closed.set()
        if self.rich:
            self.bar.stop()


def drive(ps: Sequence, layout, *, guard: signals.Guard, stages: list[list[int]], checkpoint_every: int,
          keep: int, freeze_diverged: bool, compact: bool, on_chunk: Callable[[dict[int, dict]], None] | None,
          stop_message: Callable[[int, int], str], max_chunks: int | None) -> list[dict]:
    """The chunk loop of every run: step the active points of the first unfinished stage, append
    their metrics rows, checkpoint them, report progress, stop on signals. Returns the rows written
    (every point's, in order). A diverged point raises :class:`Diverged` (``freeze_diverged`` False)
    or is frozen at its last good checkpoint while the others go on. ``ps``: the session's points
    (:class:`nmrl.runs.layout.Point`), as ``layout`` holds them; ``guard``: the session's signal
    guard (:func:`guarded`)."""
    writer = dist.is_writer()  # several processes: only process 0 writes (nmrl/runs/distributed.py)
    ckpts = [checkpoint.Checkpointer(p.dir, keep=keep, every_steps=checkpoint_every * p.cfg.budget.chunk_steps)
             if writer else None for p in ps]
    done = np.zeros(len(ps), bool)
    dist.barrier("drive")  # several processes: every one has compiled (counters() may gather)
    for i, (p, (step, trials, div)) in enumerate(zip(ps, layout.counters(), strict=True)):
        done[i] = budget_done(p.cfg, step, trials) or (freeze_diverged and (div or p.frozen))
    rows: list[dict] = []
    unsaved: set[int] = set()  # points whose newest metrics row has no checkpoint yet
    n_chunks = 0

    def save(i: int) -> None:
        guard.at("saving")
        one = layout.state(i)  # every process (a gather when there are several)
        if writer:
            ckpts[i].save(one, ps[i].cfg)
            if compact:
                checkpoint.save_compact(ps[i].dir, one, ps[i].cfg)
        unsaved.discard(i)
        guard.at("training")

    stop = guard  # ``stop.signal``: the first signal received (or agreed on by every process)
    guard.at("training")
    try:
        while not done.all():
            # several processes: start every chunk together (their compiles and process 0's saves take
            # different times; the collectives inside a chunk would wait only gloo's own 30 s)
            dist.barrier(f"chunk-{n_chunks}")
            stage = next(st for st in stages if not all(done[i] for i in st))
            active = np.zeros(len(ps), bool)
            active[[i for i in stage if not done[i]]] = True
            t0 = time.time()
            with guard.chunk():  # what a supervisor's grace may cut (nmrl/runs/signals.py)
                ms = allocate(lambda: layout.run(active), "running a chunk", ps[0].cfg)
            wall = time.time() - t0
            n_active = int(active.sum())
            new: dict[int, dict] = {}
            want = np.zeros(len(ps), bool)  # the points this process would checkpoint now
            for i, p in enumerate(ps):
                if not active[i]:
                    continue
                row = metrics_row(p.cfg, ms[i], wall, points=n_active)
                if writer:
                    append_metrics(p.dir, row)
                rows.append(row)
                new[i] = row
                if is_diverged(row):
                    done[i] = True  # its last good checkpoint is kept; frozen from now on
                    if not freeze_diverged:
                        last = ckpts[i].latest_step() if writer else "the newest"
                        norms = ", ".join(f"{k.removesuffix('_norm')} norm {row[k]:.3g}"
                                          for k in learners.norm_keys(row))
                        kept = (f"the last good checkpoint (step {last}) is kept in {p.dir}" if last is not None
                                else "no checkpoint was kept (it diverged in its first chunk)")
                        raise Diverged(
                            f"training diverged at step {row['step']}: an update took a parameter norm past the "
                            f"limit {p.cfg.budget.max_param_norm:g} (or to a non-finite value) and was rejected, the "
                            f"parameters frozen at their last accepted values ({norms}); {kept}. Try smaller "
                            f"step sizes.")
                    continue
                finished = budget_done(p.cfg, row["step"], row["trials"])
                want[i] = (finished or checkpoint_every == 1 or stop.signal is not None
                           or (writer and ckpts[i].should_save(row["step"])))
                if finished:
                    done[i] = True
            # several processes: process 0's checkpoint decisions, and a signal that reached any of them
            signum, want = _agreed(stop.signal, want, f"decide-{n_chunks}")
            for i, row in new.items():
                if is_diverged(row):
                    continue
                if want[i] or signum is not None:
                    save(i)
                else:
                    unsaved.add(i)
            if on_chunk is not None:
                on_chunk(new)
            n_chunks += 1
            if not dist.active():  # one process: a signal during on_chunk stops now, too
                signum = stop.signal
            if signum is not None:
                stop.signal = signum
                for i in sorted(unsaved):  # the signal came after this chunk's saves
                    save(i)
                step = max(r["step"] for r in new.values()) if new else 0
                print(stop_message(stop.signal, step), file=sys.stderr, flush=True)
                raise Stopped(stop.signal, step, rows)
            if max_chunks is not None and n_chunks >= max_chunks:
                break
    finally:
        guard.at("finishing")
        for c in ckpts:
            if c is not None:
                c.close()
    return rows


def _agreed(signum: int | None, want: np.ndarray, name: str) -> tuple[int | None, np.ndarray]:
    """``(signal, save mask)`` every process acts on after a chunk: the largest signal number any
    process received (None: none) and process 0's checkpoint decisions (one small collective; one
    process: its own). The processes meet at barrier ``name`` first: one may reach the collective
    long after another (process 0 writes the metrics; a loaded machine), and a collective waits
    only gloo's own 30 s for its peers, a barrier :func:`nmrl.runs.distributed.barrier_timeout_s`."""
    if not dist.active():
        return signum, want
    dist.barrier(name)
    table = dist.exchange(np.concatenate([[signum or 0], want.astype(np.int32)]))
    s = int(table[:, 0].max())
    return (s or None), table[0, 1:].astype(bool)


def progress_table(names: Sequence[str], rows_by_point: dict, elapsed: float, due: str = "") -> str:
    """The sweep's progress: a head line (the points, the time, ``due``: when the next save is due)
    and every point's latest metrics."""
    lines = [f"sweep: {len(names)} points, {elapsed:,.0f} s" + (f"; {due}" if due else "")]
    w = max(len(n) for n in names)
    for name in names:
        r = rows_by_point.get(name)
        if r is None:
            continue
        flag = "  DIVERGED" if r["diverged"] else ""
        lines.append(f"  {name:<{w}}  trials {r['trials']:>8,}  steps {r['step']:>8,}  "
                     f"avg reward {r['avg_reward']:+.3f}  speed {r['forward_speed']:+.2f} m/s{flag}")
    return "\n".join(lines)
