"""Checkpoints (nmrl.runs.checkpoint): exact resume, bad checkpoints, keep, policy-only restore, killed saves.

One tiny trainer (4 environments, 5 steps a chunk, 8 hidden units) is compiled once per module; the
compiled chunk goes into a persistent JAX compilation cache that the killed-process subprocesses
share, so they do not compile it again.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys

import jax
import numpy as np
import pytest

from nmrl import options
from nmrl.runs import checkpoint
from nmrl.runs.checkpoint import CheckpointError
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train

REPO = pathlib.Path(__file__).resolve().parents[1]
# orbax leaves an asyncio callback behind when a restore fails ("Event loop is closed"); harmless.
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")

CFG = options.build(TrainConfig, num_envs=4, chunk_steps=5, hidden_actor=8, hidden_critic=8, steps=15, seed=0)


def _same(a, b) -> bool:
    """Bit-identical pytrees (structure, shapes, dtypes, values; NaN == NaN)."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    if ta != tb or len(la) != len(lb):
        return False
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        if x.shape != y.shape or x.dtype != y.dtype or x.tobytes() != y.tobytes():
            return False
    return True


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """A persistent compilation cache for this module and its subprocesses."""
    from jax._src import compilation_cache as cc

    old = jax.config.jax_compilation_cache_dir
    d = old or str(tmp_path_factory.mktemp("jax_cache"))
    if not old:
        jax.config.update("jax_compilation_cache_dir", d)
        cc.reset_cache()
    yield d
    if not old:
        jax.config.update("jax_compilation_cache_dir", None)
        cc.reset_cache()


class Reference:
    """An uninterrupted run: states and chunk metrics after k chunks, computed on demand."""

    def __init__(self):
        self.trainer = make_train(CFG)
        self.chunk = jax.jit(self.trainer.chunk)
        self.states = [jax.device_put(jax.jit(self.trainer.init)(jax.random.PRNGKey(CFG.budget.seed)))]
        self.metrics = [None]

    def state(self, k: int):
        while len(self.states) <= k:
            ts, m = self.chunk(self.states[-1])
            self.states.append(ts)
            self.metrics.append(jax.device_get(m))
        return self.states[k]


@pytest.fixture(scope="module")
def ref(cache_dir):
    return Reference()


@pytest.fixture(scope="module")
def good_run(ref, tmp_path_factory):
    """A run directory with one checkpoint at step 5 (after one chunk)."""
    run = tmp_path_factory.mktemp("good_run")
    checkpoint.save(run, ref.state(1), ref.trainer.config, extra={"note": "one chunk"})
    return run


def _copy_run(src: pathlib.Path, dst: pathlib.Path) -> pathlib.Path:
    shutil.copytree(src, dst)
    return dst


# ----------------------------------------------------------------------------- round trip


def test_resume_equals_uninterrupted(ref, tmp_path):
    straight = ref.state(3)
    run = tmp_path / "run"
    path = checkpoint.save(run, ref.state(1), ref.trainer.config)
    assert path == run / "checkpoints" / "5" and path.is_dir()

    fresh = make_train(CFG)  # a new trainer, as in a new process
    ts = checkpoint.restore(run, fresh)
    assert _same(ts, ref.state(1))
    leaf = jax.tree_util.tree_leaves(ts)[0]
    assert leaf.committed and leaf.devices() == {jax.devices()[0]}
    chunk = jax.jit(fresh.chunk)
    ts, m2 = chunk(ts)
    ts, m3 = chunk(ts)
    assert chunk._cache_size() == 1  # restored arrays did not force a second compile
    assert int(ts.step) == 15
    assert _same(ts.theta, straight.theta) and _same(ts.v, straight.v)
    assert _same(ts.slots.z, straight.slots.z) and _same(ts.slots.y, straight.slots.y)
    assert _same(ts, straight)
    assert _same(jax.device_get(m2), ref.metrics[2]) and _same(jax.device_get(m3), ref.metrics[3])


def test_metadata_and_config(good_run, ref):
    meta = checkpoint.load_metadata(good_run)
    assert meta["schema"] == checkpoint.SCHEMA_VERSION and meta["step"] == 5
    for dist in ("nmrl", "jax", "jaxlib", "mujoco", "flax", "orbax-checkpoint", "numpy"):
        assert meta["versions"][dist], dist
    assert meta["versions"]["jax"] == jax.__version__
    assert meta["config"] == options.flat(ref.trainer.config)
    assert meta["model_file"] == "models/half_cheetah.xml" and len(meta["model_sha256"]) == 64
    assert "git_commit" in meta
    assert meta["extra"] == {"note": "one chunk"}
    json.dumps(meta, allow_nan=False)
    assert checkpoint.load_config(good_run) == ref.trainer.config
    assert checkpoint.all_steps(good_run) == [5] and checkpoint.latest_step(good_run) == 5


def test_restore_policy_matches_full_state(good_run, ref):
    cfg, theta, v = checkpoint.restore_policy(good_run)
    assert cfg == ref.trainer.config
    assert _same(theta, ref.state(1).theta) and _same(v, ref.state(1).v)


def test_keep_last_k(ref, tmp_path):
    ts = ref.state(1)
    run = tmp_path / "run"
    for s in (1, 2, 3, 4, 5):
        checkpoint.save(run, ts.replace(step=np.int32(s)), ref.trainer.config, keep=2)
    assert checkpoint.all_steps(run) == [4, 5]
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["4", "5"]
    # re-saving an existing step replaces it
    checkpoint.save(run, ts.replace(step=np.int32(5)), ref.trainer.config, keep=2, extra={"again": True})
    assert checkpoint.all_steps(run) == [4, 5]
    assert checkpoint.load_metadata(run, 5)["extra"] == {"again": True}
    assert checkpoint.load_metadata(run, 4)["step"] == 4


def test_optimizer_state_is_saved(good_run, ref):
    """The optax states of actor and critic are part of the saved TrainState and come back exactly."""
    layout = checkpoint.load_metadata(good_run)["state_layout"]
    for part in ("opt_theta", "opt_v"):
        assert f"{part}.count" in layout and f"{part}.hyperparams.learning_rate" in layout
    ts = checkpoint.restore(good_run, ref.trainer)
    assert _same(ts.opt_theta, ref.state(1).opt_theta) and _same(ts.opt_v, ref.state(1).opt_v)


# ------------------------------------------------- checkpoints written before the optimizer state

OLD_RUN = REPO / "tests" / "data" / "schema1_sgd_run"


def test_restore_checkpoint_without_optimizer_state(tmp_path):
    """A checkpoint of the hand-written update (tests/data/schema1_sgd_run, made by
    tests/data/make_schema1_sgd_checkpoint.py with the code of a849a9d) has no optimizer state. It
    restores with fresh optimizer states, and one chunk from its step 5 reproduces that code's own
    step 10."""
    run = _copy_run(OLD_RUN, tmp_path / "old")
    layout = checkpoint.load_metadata(run, 5)["state_layout"]
    assert not any(n.startswith("opt_") for n in layout)  # really the old layout
    cfg = checkpoint.load_config(run)
    trainer = make_train(cfg)
    ts5 = checkpoint.restore(run, trainer, step=5)
    ts10 = checkpoint.restore(run, trainer, step=10)
    fresh = trainer.init_opt(ts5.theta, ts5.v, ts5.hyper)
    assert _same((ts5.opt_theta, ts5.opt_v), fresh)
    assert int(ts5.opt_theta.count) == 0 and int(ts5.step) == 5
    assert float(ts5.opt_theta.hyperparams["learning_rate"]) == np.float32(cfg.beta_theta)
    assert float(ts5.opt_v.hyperparams["learning_rate"]) == np.float32(cfg.beta_v)
    leaf = jax.tree_util.tree_leaves(ts5.opt_theta)[0]
    assert leaf.committed and leaf.devices() == {jax.devices()[0]}
    out, m = jax.jit(trainer.chunk)(ts5)
    assert int(out.step) == 10 and int(m["periods_in_chunk"]) > 0
    # bit for bit on the machine that made the fixture; elsewhere (another CPU's XLA) to float rounding
    if not (_same(out.theta, ts10.theta) and _same(out.v, ts10.v) and _same(out.slots, ts10.slots)):
        for part in ("theta", "v"):
            got, want, start = (np.concatenate([np.ravel(x) for x in jax.tree.leaves(getattr(t, part))])
                                for t in (out, ts10, ts5))
            assert np.max(np.abs(want - start)) > 1e-2, part  # the parameters moved in that chunk
            assert np.max(np.abs(got - want)) <= 1e-4 * np.max(np.abs(want - start)), part
    # the old compact continuation state (step 5) restores too, with fresh optimizer states
    cts = checkpoint.restore_compact(run, trainer)
    assert int(cts.step) == 5 and _same(cts.theta, ts5.theta) and _same(cts.v, ts5.v)
    assert int(cts.opt_v.count) == 0


def test_partial_optimizer_state_is_rejected(good_run, ref, tmp_path):
    """Only a checkpoint with no optimizer state at all is migrated; a partial one is an error."""
    run = _copy_run(good_run, tmp_path / "run")
    meta = checkpoint.load_metadata(run)
    layout = {k: v for k, v in meta["state_layout"].items() if not k.startswith("opt_v.")}
    _edit_meta(run, state_layout=layout)
    msg = _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5", "does not fit")
    assert "opt_v" in msg


# ----------------------------------------------------------------------------- bad checkpoints


def _raises(fn, path, *words):
    with pytest.raises(CheckpointError) as e:
        fn()
    msg = str(e.value)
    assert str(path) in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def test_missing_and_empty(tmp_path, ref):
    missing = tmp_path / "nope"
    _raises(lambda: checkpoint.latest_step(missing), missing, "does not exist")
    _raises(lambda: checkpoint.restore_policy(missing), missing)
    _raises(lambda: checkpoint.restore(missing, ref.trainer), missing)
    no_ck = tmp_path / "no_ck"
    no_ck.mkdir()
    _raises(lambda: checkpoint.load_metadata(no_ck), no_ck, "no checkpoints")
    (no_ck / "checkpoints").mkdir()
    assert checkpoint.latest_step(no_ck) is None and checkpoint.all_steps(no_ck) == []
    _raises(lambda: checkpoint.restore(no_ck, ref.trainer), no_ck, "no finished checkpoint")
    (no_ck / "checkpoints" / "10.orbax-checkpoint-tmp-123").mkdir()
    _raises(lambda: checkpoint.restore_policy(no_ck), no_ck, "unfinished")


def test_unknown_step(good_run, ref):
    _raises(lambda: checkpoint.restore(good_run, ref.trainer, step=7), good_run, "step 7", "[5]")


def _data_files(run: pathlib.Path, item: str) -> list[pathlib.Path]:
    files = [p for p in (run / "checkpoints" / "5" / item).rglob("*") if p.is_file()]
    data = [p for p in files if p.parent.name == "d"]
    assert data, files
    return data


def test_deleted_file(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    for p in _data_files(run, "state"):
        p.unlink()
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5", "state")
    # the policy item is separate and still readable
    checkpoint.restore_policy(run)
    for p in _data_files(run, "policy"):
        p.unlink()
    _raises(lambda: checkpoint.restore_policy(run), run / "checkpoints" / "5", "policy")


def test_garbage_file(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    rng = np.random.default_rng(0)
    for p in _data_files(run, "state"):
        p.write_bytes(rng.integers(0, 256, p.stat().st_size, dtype=np.uint8).tobytes())
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5")
    for p in (run / "checkpoints" / "5" / "state").glob("*manifest*"):
        p.write_bytes(b"garbage")
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5")


def test_truncated_file(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    for p in _data_files(run, "state"):
        data = p.read_bytes()
        p.write_bytes(data[: len(data) // 2])
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5")


def _edit_meta(run: pathlib.Path, **changes) -> None:
    f = run / "checkpoints" / "5" / "meta" / "metadata"
    meta = json.loads(f.read_text())
    meta.update(changes)
    f.write_text(json.dumps(meta))


def test_garbage_metadata(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    (run / "checkpoints" / "5" / "meta" / "metadata").write_text("{not json")
    _raises(lambda: checkpoint.load_metadata(run), run / "checkpoints" / "5", "meta")
    _raises(lambda: checkpoint.restore_policy(run), run / "checkpoints" / "5")
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5")


def test_digest_detects_changed_data(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    _edit_meta(run, state_digest="0" * 64, policy_digest="1" * 64)
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5", "digest")
    _raises(lambda: checkpoint.restore_policy(run), run / "checkpoints" / "5", "digest")


def test_other_model(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    _edit_meta(run, model_sha256="ab" * 32)
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5", "another model")
    _raises(lambda: checkpoint.restore_policy(run), run / "checkpoints" / "5", "another model")
    checkpoint.restore_policy(run, check_model=False)


def test_other_schema(good_run, ref, tmp_path):
    run = _copy_run(good_run, tmp_path / "run")
    _edit_meta(run, schema=99)
    _raises(lambda: checkpoint.restore(run, ref.trainer), run / "checkpoints" / "5", "schema")


@pytest.mark.parametrize("field,value", [("num_envs", 8), ("hidden_actor", 16), ("hidden_critic", 4),
                                         ("chunk_steps", 7), ("control_dt", 0.01), ("l", 5)])
def test_incompatible_config(good_run, ref, field, value):
    other = ref.trainer._replace(config=options.replace(ref.trainer.config, **{field: value}))
    msg = _raises(lambda: checkpoint.restore(good_run, other), good_run / "checkpoints" / "5", field)
    assert "incompatible" in msg


def test_budget_may_change(good_run, ref):
    other = ref.trainer._replace(config=options.replace(ref.trainer.config, steps=1000))
    assert _same(checkpoint.restore(good_run, other), ref.state(1))


# ----------------------------------------------------------------------------- signals inside a save

# A hook inside orbax's save (the same code for this test process and the subprocesses): once the
# checkpoint's metadata item has been written into the step's temporary directory -- the state and
# policy items are written too or being written, nothing is renamed yet -- it records what the
# checkpoints directory holds and sends ``sig`` to its own process: the signal lands inside a save,
# every time. (orbax 0.12's JsonCheckpointHandler._save_fn writes the metadata JSON.)
_HOOK = r"""
import os
import pathlib
from orbax.checkpoint._src.handlers import json_checkpoint_handler as _jh

def install_signal_inside_save(sig, at_step, seen):
    save_fn = _jh.JsonCheckpointHandler._save_fn

    async def signalling_save_fn(self, x, directory):
        await save_fn(self, x, directory)
        if isinstance(x, dict) and x.get("step") == at_step and "state_digest" in x and not seen:
            ckpts = next(p for p in pathlib.Path(str(directory)).parents if p.name == "checkpoints")
            seen.append(sorted(p.name for p in ckpts.iterdir()))
            os.kill(os.getpid(), sig)

    _jh.JsonCheckpointHandler._save_fn = signalling_save_fn
    return save_fn
"""
_hook_ns: dict = {}
exec(_HOOK, _hook_ns)


def _mid_save(names: list[str], step: int) -> bool:
    """The checkpoints directory, seen from inside the save of ``step``: that step only as a tmp dir."""
    return str(step) not in names and any(n.startswith(f"{step}.orbax-checkpoint-tmp") for n in names)


TRAIN_ARGS = ["--num-envs", "4", "--chunk-steps", "5", "--hidden-actor", "8", "--hidden-critic", "8", "--seed", "0",
              "--devices", "1", "--quiet"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_inside_a_save_finishes_it_then_stops_and_resume_continues(ref, tmp_path, capsys, sig):
    """``nmrl train`` gets SIGTERM/SIGINT while it writes the checkpoint of step 10: the save completes
    (the checkpoint is the uninterrupted run's state, bit for bit), the run stops with 128 + signal,
    and ``--resume`` continues to the uninterrupted run's state at step 15."""
    from orbax.checkpoint._src.handlers import json_checkpoint_handler as jh

    from nmrl import cli
    from nmrl.runs import driver as nmrl_run

    run = tmp_path / "run"
    seen: list = []
    save_fn = _hook_ns["install_signal_inside_save"](sig, 10, seen)
    try:
        rc = cli.main(["train", *TRAIN_ARGS, "--steps", "15", "--out", str(run)])
    finally:
        jh.JsonCheckpointHandler._save_fn = save_fn
    err = capsys.readouterr().err
    assert len(seen) == 1 and _mid_save(seen[0], 10), seen  # the signal landed inside the save of step 10
    assert rc == 128 + sig, err[-2000:]
    assert f"stopped by signal {int(sig)} at step 10 (saved)" in err
    assert checkpoint.all_steps(run) == [5, 10]
    assert not [p for p in (run / "checkpoints").iterdir() if "tmp" in p.name]
    assert _same(checkpoint.restore(run, make_train(CFG)), ref.state(2))  # complete, not half-written
    assert checkpoint.load_metadata(run, 10)["state_digest"]
    assert cli.main(["train", "--resume", "--out", str(run), "--quiet"]) == 0
    assert checkpoint.latest_step(run) == 15
    assert _same(checkpoint.restore(run, make_train(CFG)), ref.state(3))
    assert [r["step"] for r in nmrl_run.read_metrics(run)] == [5, 10, 15]


# ----------------------------------------------------------------------------- killed processes

_SCRIPT = _HOOK + r"""
import json, signal, sys
import jax
from nmrl.runs import checkpoint
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train
from nmrl import options
cfg = options.build(TrainConfig, **json.loads(sys.argv[2]))
install_signal_inside_save(int(sys.argv[3]), 10, [])
tr = make_train(cfg)
ts = jax.device_put(jax.jit(tr.init)(jax.random.PRNGKey(cfg.budget.seed)))
chunk = jax.jit(tr.chunk)
for _ in range(3):
    ts, _ = chunk(ts)
    checkpoint.save(sys.argv[1], ts, tr.config, keep=3)
print("not killed", flush=True)
"""


def test_killed_inside_a_save_leaves_the_previous_checkpoint_restorable(ref, cache_dir, tmp_path):
    """SIGKILL, or SIGTERM without a handler, inside the save of step 10 (the hook above): the process
    dies, step 10 is left as an unfinished tmp dir only, step 5 restores bit for bit, and the run can
    save again into the same directory (the tmp dir is cleaned up)."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=cache_dir,
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    ref.state(1)  # the chunk is compiled (and in the persistent cache) before the children start
    runs = {sig: tmp_path / f"run_{sig.name}" for sig in (signal.SIGKILL, signal.SIGTERM)}
    procs = {
        sig: subprocess.Popen([sys.executable, "-c", _SCRIPT, str(run), json.dumps(options.flat(CFG)),
                               str(int(sig))], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        for sig, run in runs.items()
    }
    try:
        for sig, p in procs.items():
            out, err = p.communicate(timeout=170)
            assert p.returncode == -sig, (sig, p.returncode, err.decode()[-3000:])
            assert b"not killed" not in out
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()

    for sig, run in runs.items():
        names = sorted(p.name for p in (run / "checkpoints").iterdir())
        assert _mid_save(names, 10) and "5" in names, (sig, names)  # died inside the save of step 10
        assert checkpoint.latest_step(run) == 5, sig
        ts = checkpoint.restore(run, ref.trainer)
        assert _same(ts, ref.state(1)), sig
        # the run can continue saving into the same directory (unfinished tmp dirs are cleaned up)
        nxt = ref.state(2)
        checkpoint.save(run, nxt, ref.trainer.config, keep=3)
        assert checkpoint.latest_step(run) == 10
        assert _same(checkpoint.restore(run, ref.trainer), nxt)
        assert not [p for p in (run / "checkpoints").iterdir() if "tmp" in p.name]


def test_tree_compact_restores_what_the_tree_checkpoint_holds(tmp_path):
    """save_tree_compact (the committed form of another learner's checkpoint, e.g. the PPO
    baseline's) gives back, bit for bit, the arrays that save_tree's orbax checkpoint gives back;
    a tree of another layout is refused by leaf name, a corrupted file by its digest."""
    rng = np.random.default_rng(0)
    tree = ({"mean": rng.normal(size=(31,)).astype(np.float32), "count": np.asarray(7, np.int32)},
            {"params": {"w": rng.normal(size=(31, 4)).astype(np.float32), "b": np.zeros(4, np.float32)}})
    template = jax.tree_util.tree_map(np.zeros_like, tree)
    checkpoint.save_tree(tmp_path, 40, tree, {"kind": "test"})
    checkpoint.save_tree_compact(tmp_path, 40, tree, {"kind": "test"})
    m1, full = checkpoint.restore_tree(tmp_path, template)
    m2, small = checkpoint.restore_tree_compact(tmp_path, template)
    assert _same(full, small) and _same(small, jax.tree_util.tree_map(jax.numpy.asarray, tree))
    assert m1["step"] == m2["step"] == 40 and m2["kind"] == "test" and m1["digest"] == m2["digest"]
    with pytest.raises(CheckpointError, match="at step 40, not 30"):
        checkpoint.restore_tree_compact(tmp_path, template, step=30)
    assert checkpoint.restore_tree_compact(tmp_path, template, step=40)[0]["step"] == 40
    wrong = ({"mean": np.zeros(30, np.float32), "count": np.asarray(0, np.int32)}, template[1])
    with pytest.raises(CheckpointError, match="mean"):
        checkpoint.restore_tree_compact(tmp_path, wrong)
    with np.load(checkpoint.compact_path(tmp_path)) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[next(k for k in arrays if k.endswith("w"))][0, 0] += 1.0
    np.savez(checkpoint.compact_path(tmp_path), **arrays)
    with pytest.raises(checkpoint.CorruptCheckpoint, match="digest"):
        checkpoint.restore_tree_compact(tmp_path, template)
    with pytest.raises(CheckpointError, match="no compact state"):
        checkpoint.restore_tree_compact(tmp_path / "nothing", template)
