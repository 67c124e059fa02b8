"""One session of the driver, the same steps for one run and for the P points of a sweep.

A session is one call of :func:`nmrl.runs.driver.train` (one run, ``nmrl train``) or of
:func:`nmrl.runs.driver.run_points` (the points of a sweep or study). Both go through
:func:`run`, which takes these steps in this order:

1. the signal guard (:func:`nmrl.runs.loop.guarded`) and the session's one-writer locks
   (:class:`Holds`, :mod:`nmrl.runs.lock`: held from before a run is read until the session ends);
2. the caller's ``read``: the points read (a resume, nmrl/runs/resume.py) or made (a fresh start:
   the checks of nmrl/runs/preflight.py, then the first allocation); nothing is written;
3. a resume with nothing left to do (every point at its budget or frozen) says so and ends, with
   no compile and nothing written; else the caller's ``admit`` checks the points read;
4. the processes meet (nmrl/runs/distributed.py: every one has read the runs before process 0
   writes), and a signal during the set-up stops the session here;
5. the points laid out on the devices (``lay_out``, nmrl/runs/layout.py), the layout shown and
   the chunk compiled (:func:`~nmrl.runs.loop.compile_or_stop`: a signal meanwhile stops the
   session before anything is written);
6. process 0 locks what is new and checks again (``claim``), the caller's ``before_start`` runs,
   and process 0 writes what every run starts with (:func:`~nmrl.runs.layout.begin_fresh`,
   :func:`~nmrl.runs.layout.begin_resumed`);
7. the chunk loop (:func:`~nmrl.runs.loop.drive`) with the session's progress display.

What differs between one run and many points is a :class:`Policy`: the layout's kind, how many
checkpoints are kept and how often they are made, whether a diverged point is frozen or stops
the session, whether the compact state is written, the progress display and the session's lines.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import pathlib
import sys
import time
from typing import Callable, Sequence

from nmrl.learners import heartbeat
from nmrl.runs import distributed as dist, preflight, signals
from nmrl.runs.layout import Point, begin_fresh, begin_resumed
from nmrl.runs.loop import Progress, budget_done, compile_or_stop, drive, guarded, next_save, progress_table

#: the layout kinds (:attr:`Policy.kind`): one run split over the devices, or P points as one program
ONE_RUN, POINTS = "one run", "points"


@dataclasses.dataclass(frozen=True)
class Policy:
    """What a session keeps, shows and says; its steps (:func:`run`) are the same for every session.

    ``kind`` is its layout's (:data:`ONE_RUN`: ``nmrl train``; :data:`POINTS`: a sweep or study)
    and sets what only one run has: a note when its budget is not a whole number of chunks, the
    run's own step in a stop before the first chunk (the points': 0), a progress bar with the
    chunk's heartbeats (the points: a table of every point's latest metrics, with ``table``).
    ``keep``: the checkpoints kept per point; ``checkpoint_every``: the chunks between two saves;
    ``freeze_diverged``: a diverged point is frozen at its last good checkpoint while the others
    go on (else :class:`~nmrl.runs.errors.Diverged` ends the session); ``compact``: every save
    also writes the compact continuation state. ``barrier``: the processes' meeting after the
    reads. ``stopped``: what a stop before the first chunk leaves and how to continue;
    ``stop_message(signal, step)``: the line of a stop in the chunk loop;
    ``nothing_to_do(points)``: the line of a resume with nothing left to do (None: no line).
    """

    kind: str
    keep: int
    checkpoint_every: int
    freeze_diverged: bool
    compact: bool
    barrier: str
    stopped: str
    stop_message: Callable[[int, int], str]
    nothing_to_do: Callable[[Sequence[Point]], str | None]
    table: bool = False


class Holds:
    """The one-writer locks a session holds (process 0 only: the others write nothing), released
    when it ends; a directory that a lock created and nothing was written to is removed again."""

    def __init__(self, guard: signals.Guard):
        self.guard = guard
        self.started = False  #: whether anything of the session was written
        self._held: list = []

    def hold(self, d: pathlib.Path, create: bool = True, on_exit: bool = False) -> None:
        """Hold ``d``'s lock (:func:`nmrl.runs.preflight.hold`; ``create``: making the directory).
        ``on_exit``: a second signal's immediate exit before the first write releases it and
        removes the directory if empty."""
        h = preflight.hold(d, create=create)
        if h is None:
            return
        self._held.append(h)
        if on_exit:
            self.guard.on_exit.append(lambda: None if self.started else h.release(remove_if_empty=True))

    def release(self) -> None:
        for h in reversed(self._held):
            h.release(remove_if_empty=not self.started)


def run(policy: Policy, read: Callable[[Holds], list[Point]], lay_out: Callable[[list[Point]], object], *,
        resume: bool, progress: bool, max_chunks: int | None, stages: list[list[int]] | None = None,
        admit: Callable[[list[Point]], None] | None = None, claim: Callable[[Holds], None] | None = None,
        before_start: Callable[[], None] | None = None, on_chunk: Callable[[], None] | None = None) -> list[dict]:
    """Run one session (the module docstring's steps); returns the metrics rows written.

    ``read(holds)`` gives the session's points (locking their directories with ``holds``);
    ``lay_out(points)`` places them on the devices (a layout of nmrl/runs/layout.py, which then
    holds their states). ``stages``: the points' stages (default: one stage of every point).
    ``admit(points)`` checks the points of a resume that has something to do; ``claim(holds)``
    (process 0, once the chunk compiled) locks what is new and checks again; ``before_start()``
    runs before the first write; ``on_chunk()`` after every chunk.
    """
    writer = dist.is_writer()
    one = policy.kind == ONE_RUN
    with guarded() as guard, contextlib.ExitStack() as cleanup:
        holds = Holds(guard)
        try:
            guard.at("starting")
            ps = read(holds)
            if resume and all(p.frozen or budget_done(p.cfg, int(p.ts.step), int(p.ts.trials)) for p in ps):
                line = policy.nothing_to_do(ps)  # nothing to continue: no compile, nothing written
                if line is not None:
                    print(line, file=sys.stderr, flush=True)
                return []
            if admit is not None:
                admit(ps)
            dist.barrier(policy.barrier)  # several processes: all have read the runs before process 0 writes
            guard.stop_setup()
            cfg = ps[0].cfg
            b = cfg.budget
            if one and b.steps is not None and b.steps % b.chunk_steps:
                end = math.ceil(b.steps / b.chunk_steps) * b.chunk_steps
                print(f"note: the budget of {b.steps} steps is not a whole number of chunks of {b.chunk_steps}: "
                      f"the run stops after whole chunks, at step {end}", file=sys.stderr, flush=True)
            at = int(ps[0].ts.step) if one else 0  # the step a stop before the first chunk reports
            done0 = int(ps[0].ts.step) if cfg.budget.steps is not None else int(ps[0].ts.trials)
            layout = lay_out(ps)
            for p in ps:
                p.ts = None  # the layout holds the states now
            progress = progress and writer
            if progress:
                print(layout.banner(), file=sys.stderr, flush=True)
            beat_to: list = []  # the progress bar's heartbeat, once it exists (nmrl/learners/heartbeat.py)
            if one and progress and cfg.environment.physics == "c":  # where the program calls the host anyway
                cleanup.enter_context(heartbeat.listening(lambda *b: beat_to and beat_to[-1](*b)))
            compile_or_stop(guard, layout, cfg, step=at, chunk=layout.chunk_name if progress else None,
                            stopped=policy.stopped)
            if writer and claim is not None:  # every check passed and the chunk compiled
                claim(holds)
            holds.started = True
            if before_start is not None:
                before_start()
            if writer:
                for p in ps:
                    if p.record is not None:
                        begin_resumed(p)
                    else:
                        begin_fresh(p)
            chunk_done, close = _display(policy, ps, progress, done0, on_chunk, beat_to)
            try:
                return drive(ps, layout, guard=guard, stages=stages or [list(range(len(ps)))],
                             checkpoint_every=policy.checkpoint_every, keep=policy.keep,
                             freeze_diverged=policy.freeze_diverged, compact=policy.compact, on_chunk=chunk_done,
                             max_chunks=max_chunks, stop_message=policy.stop_message)
            finally:
                close()
        finally:
            holds.release()


def _display(policy: Policy, ps: Sequence[Point], progress: bool, done0: int, on_chunk: Callable[[], None] | None,
             beat_to: list) -> tuple[Callable[[dict[int, dict]], None], Callable[[], None]]:
    """``(after each chunk, at the end)`` of the session's progress display: one run's bar (its
    heartbeat appended to ``beat_to``), or the points' table (with ``policy.table``); ``on_chunk()``
    after every chunk."""
    cfg = ps[0].cfg
    if policy.kind == ONE_RUN:
        bar = Progress(cfg, progress, done0)
        beat_to.append(bar.beat)

        def bar_chunk(new: dict[int, dict]) -> None:
            bar.update(new[0])
            if on_chunk is not None:
                on_chunk()

        return bar_chunk, bar.close
    names = [p.name for p in ps]
    last_rows: dict = {}
    t_start = time.time()

    def table_chunk(new: dict[int, dict]) -> None:
        last_rows.update({names[i]: r for i, r in new.items()})
        if on_chunk is not None:
            on_chunk()
        if progress and policy.table:
            r = min(new.values(), key=lambda r: r["step"], default=None)  # the point furthest behind
            due = next_save(r["step"], cfg.budget.chunk_steps, policy.checkpoint_every, r["wall_s"]) if r else ""
            print(progress_table(names, last_rows, time.time() - t_start, due), file=sys.stderr, flush=True)

    return table_chunk, lambda: None
