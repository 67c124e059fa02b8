"""Continuing a run: one function for every resume, of a run or of every point of a sweep.

A run directory has one identity, the config it was created with (``config.json``; see
nmrl/runs/checkpoint.py and nmrl/runs/store.py). A resume goes through :func:`load_resume`: it
continues the run with its own config, only the budget (:data:`BUDGET_FIELDS`) may change
(recorded in ``config.json`` and ``resumes.jsonl`` by :func:`nmrl.runs.layout.begin_resumed`), from
its newest checkpoint or the one asked for (else from its compact continuation state, else from
the start if it never ran a chunk). It refuses options that would change the run
(:func:`given_changes`) and a checkpoint of another run or a corrupted one (naming the newest good
one). Every refusal happens before anything is written: this module only reads.
"""

from __future__ import annotations

import pathlib
import sys
import time

import jax

from nmrl import learners, options
from nmrl.learners.contract import Config
from nmrl.runs import checkpoint, distributed as dist
from nmrl.runs.errors import RunError
from nmrl.runs.preflight import check_config, preflight
from nmrl.runs.store import CONFIG_FILE, METRICS_FILE, read_metrics

#: Config fields a resume may change (the budget); the others are the run's identity.
BUDGET_FIELDS = checkpoint.RESUMABLE_FIELDS


def existing_step(run_dir: pathlib.Path) -> int | None:
    """The newest checkpoint step in ``run_dir``, or None when there is none (or no directory)."""
    try:
        return checkpoint.latest_step(run_dir)
    except checkpoint.CheckpointError:
        return None


def given_changes(ident: Config, given: dict, out: pathlib.Path) -> None:
    """Refuse options given with ``--resume`` that would change the run's identity, naming them all."""
    base = ident.resolved()
    bad = []
    fields = options.leaves(type(ident))
    for k, v in given.items():
        if k in BUDGET_FIELDS:
            continue
        if k not in fields:
            bad.append(f"--{k.replace('_', '-')} {v!r} (the run's learner {learners.of(ident).name!r} has no such "
                       f"option)")
            continue
        try:
            new = options.value(options.replace(ident, **{k: v}).resolved(), k)
        except (TypeError, ValueError):
            new = v
        if new != options.value(base, k):
            bad.append(f"--{k.replace('_', '-')} {v!r} (the run has {options.value(base, k)!r})")
    if bad:
        raise RunError(f"--resume continues the run in {out} with its own config; these options would change "
                       f"it: {', '.join(bad)}; only the budget (--steps or --trials) may change")


def _budget(cfg: Config) -> dict:
    return {k: getattr(cfg.budget, k) for k in BUDGET_FIELDS}


def load_resume(cfg: Config, out: pathlib.Path, given: dict | None, step: int | None, env=None):
    """Everything a resume of the run in ``out`` checks and reads, nothing written:
    ``(config, trainer, state, record)``, the config with the session's budget (``given``'s, else
    ``cfg``'s, else the run's own), the state from the checkpoint ``step`` or the newest one, else from
    the compact continuation state, else (a run that never finished a chunk) the initial state.
    ``record`` is the line for ``resumes.jsonl`` (:func:`nmrl.runs.layout.begin_resumed` writes it)."""
    if not out.is_dir():
        why = "it does not exist" if not out.exists() else "it is not a directory"
        raise RunError(f"--resume: no checkpoint found in {out} ({why})")
    run_cfg = checkpoint.load_run_config(out)
    source = str(out / CONFIG_FILE)
    try:
        steps = checkpoint.all_steps(out)
    except checkpoint.CheckpointError:
        if (out / checkpoint.CHECKPOINTS).is_dir():
            raise
        steps = []
    compact = not steps and checkpoint.has_compact(out)
    if not steps:
        rows = read_metrics(out)
        if run_cfg is None or step is not None:
            why = (f"; its {METRICS_FILE} has {len(rows)} row(s) that cannot be continued: choose another --out"
                   if rows else "")
            raise RunError(f"--resume: no checkpoint found in {out}" + why)
        if rows and not compact and dist.is_writer():  # stopped before its first save: it starts again
            print(f"nmrl: note: the run in {out} has no checkpoint yet (it was stopped before its first save): it "
                  f"starts again from step 0 with its own config, and its {len(rows)} metrics row(s) are replaced",
                  file=sys.stderr, flush=True)
    if run_cfg is None:  # a run directory without config.json (written by checkpoint.save alone)
        source = f"the newest checkpoint ({out / checkpoint.CHECKPOINTS / str(steps[-1])})"
        for s in reversed(steps):
            try:
                run_cfg = checkpoint.load_config(out, s)
                break
            except checkpoint.CorruptCheckpoint:
                if s == steps[0]:
                    raise
    has_config = (out / CONFIG_FILE).is_file()
    if type(cfg) is not type(run_cfg):  # before the options, which are the other learner's
        raise RunError(f"--resume continues the run in {out} with its own learner {learners.of(run_cfg).name!r}; "
                       f"--learner {learners.of(cfg).name} would change it")
    if given is not None:
        given_changes(run_cfg, given, out)
        new_budget = {k: given.get(k) for k in BUDGET_FIELDS}
    else:  # library callers: the budget of ``cfg``, if it has one
        new_budget = _budget(cfg)
    if all(v is None for v in new_budget.values()):
        new_budget = None
    trainer = learners.of(run_cfg).make(run_cfg, env=env)
    preflight(run_cfg, trainer)  # before the state is restored or made: sizes beyond the machine

    def load(s: int):
        meta = checkpoint.load_metadata(out, s)
        checkpoint.check_identity(meta, run_cfg, source)
        return meta, checkpoint.restore(out, trainer, step=s)

    if compact:  # no full checkpoint (e.g. a fresh clone of published results): statistically equal
        meta = {"path": str(checkpoint.compact_path(out))}
        ts = checkpoint.restore_compact(out, trainer)
        old_budget = _budget(run_cfg)
    elif not steps:  # created, stopped before its first checkpoint: start it again, as it would have run
        meta, ts = None, jax.jit(trainer.init)(jax.random.PRNGKey(run_cfg.budget.seed))
        old_budget = _budget(run_cfg)
    else:
        start = steps[-1]
        rows = read_metrics(out) if step is None else []
        if rows and rows[-1]["step"] < steps[-1] and any(s <= rows[-1]["step"] for s in steps):
            # the newest chunk's row was lost (a partial line dropped): run that chunk again from the newest
            # checkpoint its rows reach, so metrics.jsonl stays whole
            start = max(s for s in steps if s <= rows[-1]["step"])
        try:  # the newest checkpoint or the one asked for (newest_good with a step: no fallback)
            s, (meta, ts), _ = checkpoint.newest_good(out, load, step if step is not None else start)
        except checkpoint.CorruptCheckpoint as e:
            if step is not None:
                raise
            good = None
            for s in reversed(steps[:-1]):
                try:
                    load(s)
                except checkpoint.CheckpointError:
                    continue
                good = s
                break
            hint = (f"resume from the newest good checkpoint with --resume --step {good}" if good is not None
                    else "no older checkpoint is readable either")
            raise RunError(f"{e}; {hint} (nothing was changed)") from e
        except checkpoint.ForeignCheckpoint as e:
            asked = step if step is not None else start
            fits = []  # only checkpoints without the mismatch are worth naming
            for s in steps:
                if s == asked:
                    continue
                try:
                    checkpoint.check_identity(checkpoint.load_metadata(out, s), run_cfg, source)
                except checkpoint.CheckpointError:
                    continue
                fits.append(s)
            if fits:
                hint = f" (checkpoints of this run: --step {fits})"
            elif has_config and len(steps) > 1:
                hint = (f"; every checkpoint in {out} differs from its {CONFIG_FILE} the same way: if it was "
                        f"edited, restore it (nothing was changed)")
            elif has_config:
                hint = f"; if {CONFIG_FILE} was edited, restore it (nothing was changed)"
            else:
                hint = ""
            raise RunError(f"{e}{hint}") from e
        old_budget = {k: meta["config"].get(k) for k in BUDGET_FIELDS}
    new = options.replace(run_cfg, **(new_budget or old_budget))
    try:
        check_config(new)
        cfg = new.resolved()
    except ValueError as e:
        raise RunError(str(e)) from e
    # config.json keeps the run's identity and states its current budget
    write_config = not has_config or _budget(cfg) != _budget(run_cfg)
    record = {"unix_time": time.time(), "from_step": int(ts.step),
              "from_checkpoint": meta["path"] if meta else None,
              "previous_budget": old_budget, "budget": _budget(cfg), "config_json_updated": write_config}
    return cfg, trainer, ts, record
