"""The identity of a run: its ``config.json`` (learner and config) and the model file.

Identity. A run directory has one identity: the config it was created with (``config.json``,
every field but the budget ``steps``/``trials``) and the model file's sha256. Every checkpoint
records its config and model hash (and, from this version on, their digest ``identity``;
checkpoints without it are checked through their config and model hash alone);
:func:`check_identity` refuses a checkpoint whose identity differs from its run's, naming both.
The learner is part of the identity (``config.json``'s ``"learner"``; none: the actor-critic,
whose identity digests therefore stay what they were before there were other learners).
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib


from nmrl import learners, options
from nmrl.paper.env import MODEL_PATH
from nmrl.runs import store
from nmrl.runs.checkpoint_files import Config, _err, _learner_of_meta, _sha256_file
from nmrl.runs.checkpoint_steps import load_metadata
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint, ForeignCheckpoint

__all__ = ['RESUMABLE_FIELDS', 'RUN_CONFIG', 'LATER_FIELDS', 'load_config', 'load_run_config', 'identity_config',
           'identity_digest', 'check_identity']

#: Config fields that may differ between a checkpoint and the trainer that resumes it (the budget);
#: every other field is part of the run's identity.
RESUMABLE_FIELDS = ("steps", "trials")
#: The run's config, written when the run is created (nmrl/runs/store.py); the reference of its identity.
RUN_CONFIG = store.CONFIG_FILE


def _config_from_meta(meta: dict) -> Config:
    path = meta.get("path", "?")
    cfg = meta["config"]
    cls = _learner_of_meta(meta).config
    known = options.leaves(cls)
    unknown = sorted(set(cfg) - set(known) - {learners.KEY})
    if unknown:
        raise CheckpointError(f"{path}: the saved config has fields this nmrl does not know: {unknown}")
    try:
        return options.build(cls, **learners.saved_fields(cls, {k: v for k, v in cfg.items() if k != learners.KEY}))
    except TypeError as e:
        raise _err(pathlib.Path(path), "the saved config is invalid", e, CorruptCheckpoint) from e


def load_config(run_dir: str | os.PathLike, step: int | None = None) -> Config:
    """The config a checkpoint was saved with (as passed to :func:`save`)."""
    return _config_from_meta(load_metadata(run_dir, step))


def _check_model(meta: dict) -> None:
    now = _sha256_file(MODEL_PATH)
    if meta["model_sha256"] != now:
        raise ForeignCheckpoint(
            f"{meta['path']}: checkpoint of another model: {meta.get('model_file')} had sha256 "
            f"{meta['model_sha256']}, {MODEL_PATH} now has {now}"
        )


def _check_config(meta: dict, config: Config) -> None:
    saved = _config_from_meta(meta)
    if type(saved) is not type(config):
        raise ForeignCheckpoint(f"{meta['path']}: checkpoint of the learner {learners.of(saved).name!r}, the "
                                f"trainer is {learners.of(config).name!r}")
    try:
        a = options.flat(saved.resolved())
    except ValueError as e:
        raise _err(pathlib.Path(meta["path"]), "the saved config is invalid", e) from e
    b = options.flat(config.resolved())
    diff = [f"{k}: checkpoint {a[k]!r} != trainer {b[k]!r}" for k in a if k not in RESUMABLE_FIELDS
            and a[k] != b[k]]
    if diff:
        raise ForeignCheckpoint(f"{meta['path']}: config incompatible with the trainer: " + "; ".join(diff))




#: Identity fields that runs with an older identity digest do not record, with the value those runs
#: had (nmrl/learners/contract.py): a field at that value is left out of the identity.
LATER_FIELDS = learners.LATER_FIELDS


def identity_config(config: Config) -> dict:
    """The fields of a run's identity: the learner's name and the resolved config without the budget
    (``RESUMABLE_FIELDS``), without a field of :data:`LATER_FIELDS` at the value every run had before
    it existed (the learner: the actor-critic)."""
    d = learners.config_dict(config.resolved())
    return {k: v for k, v in d.items()
            if k not in RESUMABLE_FIELDS and not (k in LATER_FIELDS and v == LATER_FIELDS[k])}


def identity_digest(config: Config, model_sha256: str | None) -> str:
    """sha256 of a run's identity (:func:`identity_config` and the model file's sha256)."""
    text = json.dumps({"config": identity_config(config), "model_sha256": model_sha256}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def load_run_config(run_dir: str | os.PathLike) -> Config | None:
    """The config ``RUN_DIR/config.json`` the run was created with (of the learner it names, the
    actor-critic if it names none); None if the run has none."""
    path = pathlib.Path(run_dir) / RUN_CONFIG
    if not path.is_file():
        return None
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise _err(path, "cannot read the run's config", e) from e
    if not isinstance(d, dict):
        raise CheckpointError(f"{path}: not a run config")
    try:
        cls = learners.get(d.get(learners.KEY) or learners.DEFAULT).config
    except ValueError as e:
        raise CheckpointError(f"{path}: {e}") from e
    known = set(options.leaves(cls)) | {learners.KEY}
    if set(d) - known:
        raise CheckpointError(f"{path}: not a run config (unknown fields {sorted(set(d) - known)})")
    try:
        cfg = options.build(cls, **learners.saved_fields(cls, {k: v for k, v in d.items() if k != learners.KEY}))
        cfg.resolved()
    except (TypeError, ValueError) as e:
        raise _err(path, "the run's config is invalid", e) from e
    return cfg


def check_identity(meta: dict, run_config: Config | None, source: str = "the run's config") -> None:
    """Refuse a checkpoint (``meta`` from :func:`load_metadata`) that is not of the run ``run_config``.

    The checkpoint's own config and model hash must agree with its recorded ``identity`` (when it
    has one: older checkpoints do not) -- else :class:`CorruptCheckpoint`; its model hash must be
    the model file's now, and every identity field of its config must equal ``run_config``'s (the
    run's ``config.json``, named ``source`` in the message) -- else :class:`ForeignCheckpoint`
    naming the fields with both values. ``run_config`` None checks the checkpoint alone.
    """
    path = pathlib.Path(meta["path"])
    saved = _config_from_meta(meta)
    try:
        mine = identity_config(saved)
        digest = identity_digest(saved, meta["model_sha256"])
    except (ValueError, TypeError) as e:
        raise _err(path, "the saved config is invalid", e, CorruptCheckpoint) from e
    recorded = meta.get("identity")
    if recorded is not None and recorded != digest:
        raise CorruptCheckpoint(f"{path}: the metadata's identity {str(recorded)[:16]}... does not match its "
                                f"own config and model hash (edited or corrupted metadata)")
    if run_config is not None:
        theirs = identity_config(run_config)
        diff = [f"{k}={mine.get(k, LATER_FIELDS.get(k))!r} in the checkpoint but "
                f"{theirs.get(k, LATER_FIELDS.get(k))!r} in {source}"
                for k in sorted(set(theirs) | set(mine)) if mine.get(k) != theirs.get(k)]
        if diff:
            raise ForeignCheckpoint(f"{path}: checkpoint of another run: " + "; ".join(diff))
    _check_model(meta)
