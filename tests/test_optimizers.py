"""The optimizer vocabulary: ``actor_opt`` / ``critic_opt`` chains of sgd, adam and
clipping by global norm, checked against independent computations.

* parsing: canonical forms; every bad spec is a ValueError naming the bad value and listing the
  allowed elements; the CLI exits with 2 and writes nothing;
* the default (the ``paper`` preset) is exactly the paper's rule: the chain ``sgd`` builds the same
  optax transformation and state as a plain ``optax.sgd`` (so checkpoints of sgd runs keep their
  layout; tests/test_checkpoint.py restores a checkpoint without optimizer state and reproduces the
  chunk of the code that wrote it), and
  an unset spec gives bit for bit the chunk of an explicit ``sgd``;
* ``clip:c,sgd`` moves theta (v) by beta * clip_c(sum_e d_e z_e) and ``sgd,clip:c`` by
  clip_c(beta sum_e d_e z_e), clip_c(g) = g min(1, c / |g|), recomputed here around every control
  step from the states (d_e and the traces, as tests/test_learner.py's hand-written update);
* ``adam``: a numpy Adam over the same pseudo-gradients (moments, bias correction, eps) matches
  at every update instant; its first step is +beta sign(sum_e d_e z_e) up to eps;
* the chain is part of the run's identity: a resume (train or sweep) with another chain is
  refused by name; a checkpoint carries the chain's state (Adam's moments) and a resume from it
  equals the uninterrupted run bit for bit.
"""

from __future__ import annotations

import dataclasses
import json
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402
import pytest  # noqa: E402

from nmrl import options
from nmrl import cli  # noqa: E402
from nmrl.runs import checkpoint  # noqa: E402
from nmrl.learners.ac_config import PRESETS, TrainConfig  # noqa: E402
from nmrl.learners.ac_train import make_train  # noqa: E402
from nmrl.learners.optimizers import OPT_VOCAB, canonical_opt, injected, parse_opt, sgd_rule  # noqa: E402

try:  # pytest puts tests/ on sys.path (rootdir-relative "prepend" import mode)
    from test_learner import flat, mlp, run_learner, tiny_config
    from tiny_env import TinyEnv
except ImportError:  # imported as the package "tests"
    from tests.test_learner import flat, mlp, run_learner, tiny_config
    from tests.tiny_env import TinyEnv

pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")


# --------------------------------------------------------------------------- parsing


@pytest.mark.parametrize("spec,canon", [
    ("sgd", "sgd"),
    ("clip:10,sgd", "clip:max_norm=10.0,sgd"),
    (" clip : max_norm=2.5 , sgd ", "clip:max_norm=2.5,sgd"),
    ("sgd,clip:0.01", "sgd,clip:max_norm=0.01"),
    ("adam", "adam:b1=0.9:b2=0.999:eps=1e-08"),
    ("adam:b2=0.99", "adam:b1=0.9:b2=0.99:eps=1e-08"),
    ("adam:0.8:0.9:1e-6", "adam:b1=0.8:b2=0.9:eps=1e-06"),
    ("clip:1,adam:eps=1e-3", "clip:max_norm=1.0,adam:b1=0.9:b2=0.999:eps=0.001"),
])
def test_canonical_form(spec, canon):
    assert canonical_opt(spec) == canon
    assert canonical_opt(canon) == canon  # a fixed point: what config.json records reads back the same


@pytest.mark.parametrize("spec,words", [
    ("adamw", ["'adamw'", "unknown optimizer", "sgd", "adam", "clip"]),
    ("sgd:0.1", ["sgd takes 0 parameter"]),
    ("clip,sgd", ["clip needs max_norm"]),
    ("clip:0,sgd", ["max_norm=0.0", "> 0"]),
    ("clip:-1,sgd", ["max_norm=-1.0", "> 0"]),
    ("clip:inf,sgd", ["max_norm='inf'", "finite"]),
    ("clip:ten,sgd", ["'ten'", "not a number"]),
    ("clip:10", ["exactly one step", "sgd or adam", "got 0"]),
    ("sgd,adam", ["exactly one step", "got 2"]),
    ("adam:b3=0.5", ["no parameter 'b3'", "b1, b2, eps"]),
    ("adam:b1=1", ["b1=1.0", "[0, 1)"]),
    ("adam:eps=0", ["eps=0.0", "> 0"]),
    ("adam:0.9:0.9:1e-8:3", ["adam takes 3 parameter"]),
    ("adam:b1=0.5:b1=0.6", ["b1 is given twice"]),
    ("", ["must be a chain", "sgd", "adam", "clip"]),
])
def test_bad_spec_names_value_and_allowed(spec, words):
    with pytest.raises(ValueError) as e:
        TrainConfig(actor_opt=spec).resolved()
    msg = str(e.value)
    assert msg.startswith(f"actor_opt={spec!r} is invalid"), msg
    for w in words:
        assert w in msg, (w, msg)
    with pytest.raises(ValueError, match=r"^critic_opt="):
        TrainConfig(critic_opt=spec).validate()


@pytest.mark.parametrize("cmd", ["train", "sweep"])
def test_cli_bad_chain_exits_2_and_writes_nothing(cmd, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [cmd, "--critic-opt", "clip:1,momentum", "--out", str(out), "--quiet"]
    if cmd == "sweep":
        argv[1:1] = ["--l", "1", "10"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("nmrl: error: critic_opt='clip:1,momentum' is invalid: unknown optimizer 'momentum'")
    assert "allowed: sgd, adam" in err and "clip:max_norm" in err
    assert not out.exists()


def test_help_documents_the_vocabulary(capsys):
    with pytest.raises(SystemExit):
        cli.main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for w in ("--actor-opt", "--critic-opt", "clip:10,sgd", "adam", "exactly one sgd or adam"):
        assert w in text, w


# --------------------------------------------------------------------------- the default is the paper's rule


def test_presets_name_the_papers_rule():
    assert set(OPT_VOCAB) == {"sgd", "adam", "clip"}
    cfg = TrainConfig().resolved()
    assert cfg.preset == "paper" and (cfg.actor_opt, cfg.critic_opt) == ("sgd", "sgd")
    assert (cfg.beta_theta, cfg.beta_v) == (2e-6, 1e-5)
    assert (PRESETS["paper"]["actor_opt"], PRESETS["paper"]["critic_opt"]) == ("sgd", "sgd")
    # a config.json written before the vocabulary (no actor_opt/critic_opt) resolves to sgd
    old = {k: v for k, v in options.flat(TrainConfig().resolved()).items()
           if k not in ("actor_opt", "critic_opt")}
    assert checkpoint.identity_config(options.build(TrainConfig, **old)) == checkpoint.identity_config(TrainConfig())


def test_every_preset_names_a_valid_rule_and_fast_keeps_its_meaning():
    for name, p in PRESETS.items():
        cfg = TrainConfig(preset=name).resolved()
        assert (cfg.beta_theta, cfg.beta_v) == (p["beta_theta"], p["beta_v"])
        assert cfg.actor_opt == canonical_opt(p["actor_opt"]) and cfg.critic_opt == canonical_opt(p["critic_opt"])
    # "fast" is what results/fig3_fast and the time-scale study ran (and what their config.json files,
    # written before the vocabulary, resolve to): plain sgd with 5x / 50x the paper's step sizes
    assert PRESETS["fast"] == {"beta_theta": 1e-5, "beta_v": 5e-4, "actor_opt": "sgd", "critic_opt": "sgd"}
    clip = TrainConfig(preset="fast_clip").resolved()
    assert (clip.beta_theta, clip.beta_v) == (1e-5, 5e-4)
    assert (clip.actor_opt, clip.critic_opt) == ("sgd,clip:max_norm=0.03", "sgd,clip:max_norm=1.0")


def test_default_chunk_equals_explicit_sgd_and_the_optax_sgd_state():
    """An unset spec (the paper preset) and an explicit 'sgd' give the same chunk bit for bit, and
    the optimizer state is the one of optax.sgd under inject_hyperparams, as before the vocabulary
    (the checkpoint layout is unchanged)."""
    env = TinyEnv(stop_prob=0.1)
    cfg = tiny_config(l=3, num_envs=4, chunk_steps=30)
    _, h_default = run_learner(cfg, env, seed=1, n_chunks=2)
    _, h_sgd = run_learner(dataclasses.replace(cfg, actor_opt="sgd", critic_opt="sgd"), env, seed=1, n_chunks=2)
    for (a, ma), (b, mb) in zip(h_default, h_sgd):
        assert _same((a, ma), (b, mb))
    ts = h_default[-1][0]
    want = injected(sgd_rule, 0.0).init(ts.theta)
    assert jax.tree.structure(ts.opt_theta) == jax.tree.structure(want)
    assert jax.tree.structure(injected(lambda lr: optax.sgd(lr), 0.0).init(ts.theta)) == jax.tree.structure(want)


# --------------------------------------------------------------------------- independent computations


def pseudo_gradients(before, after):
    """sum_e d_e z_e and sum_e d_e y_e of one control step, recomputed from the states around it
    (d_e = r_bar + gamma^l V(s_next; v) - V(s_start; v) where the period ended, else 0; the
    traces after the step hold this period's term); float64 vectors, and the count of periods."""
    sl = after.slots
    completed = (np.asarray(sl.ar.i) == 0) & (np.asarray(sl.env.done) == 0)
    value = lambda s: mlp(before.v, s)[..., 0]  # noqa: E731
    d = np.asarray(sl.rbar + sl.gpow * value(sl.env.obs) - value(sl.s_start), np.float64)
    d = np.where(completed, d, 0.0)
    per_env = lambda tr: np.stack([flat(jax.tree.map(lambda x: x[e], tr)) for e in range(d.shape[0])])  # noqa: E731
    return d @ per_env(sl.z), d @ per_env(sl.y), int(completed.sum())


def adam_state(opt) -> optax.ScaleByAdamState:
    """The one ScaleByAdamState inside an optimizer state (wherever the chain puts it)."""
    found = [x for x in jax.tree.leaves(opt, is_leaf=lambda x: isinstance(x, optax.ScaleByAdamState))
             if isinstance(x, optax.ScaleByAdamState)]
    assert len(found) == 1, found
    return found[0]


EPS32 = float(np.finfo(np.float32).eps)


def clip(g: np.ndarray, c: float) -> np.ndarray:
    n = np.linalg.norm(g)
    return g * min(1.0, c / n) if n > 0 else g


def _step_through(cfg, env, n_steps, key=5):
    """(before, after) state pairs of ``n_steps`` one-step chunks."""
    trainer = make_train(options.replace(cfg, chunk_steps=1, steps=n_steps), env)
    chunk = jax.jit(trainer.chunk)
    ts = jax.jit(trainer.init)(jax.random.key(key))
    pairs = []
    for _ in range(n_steps):
        before = ts
        ts, _ = chunk(ts)
        pairs.append((before, ts))
    return trainer, pairs


@pytest.mark.parametrize("where", ["before", "after"])
def test_clip_by_global_norm_equals_hand_computation(where):
    """'clip:c,sgd': p += beta clip_c(S); 'sgd,clip:c': p += clip_c(beta S), S the summed
    pseudo-gradient of the step; the threshold is set so that some steps clip and some do not."""
    env = TinyEnv(stop_prob=0.1)
    base = tiny_config(l=2, num_envs=6)
    # the threshold: the median norm of S (theta) and of S (v) in the unclipped run
    _, pairs = _step_through(base, env, 30)
    gs = [pseudo_gradients(b, a) for b, a in pairs]
    c_t = float(np.median([np.linalg.norm(g[0]) for g in gs if g[2]]))
    c_v = float(np.median([np.linalg.norm(g[1]) for g in gs if g[2]]))
    if where == "after":
        c_t, c_v = c_t * base.beta_theta, c_v * base.beta_v
    spec = (lambda c: f"clip:{c!r},sgd") if where == "before" else (lambda c: f"sgd,clip:{c!r}")
    cfg = dataclasses.replace(base, actor_opt=spec(c_t), critic_opt=spec(c_v))
    trainer, pairs = _step_through(cfg, env, 30)
    clipped = {"theta": 0, "v": 0}
    for t, (before, after) in enumerate(pairs):
        s_t, s_v, n = pseudo_gradients(before, after)
        for what, s, beta, c in (("theta", s_t, cfg.beta_theta, c_t), ("v", s_v, cfg.beta_v, c_v)):
            old, got = flat(getattr(before, what)), flat(getattr(after, what))
            if n == 0:
                np.testing.assert_array_equal(got, old)
                continue
            u = beta * clip(s, c) if where == "before" else clip(beta * s, c)
            raw = s if where == "before" else beta * s
            clipped[what] += np.linalg.norm(raw) > c
            # float32 rounding of p + u: a few ulps of the parameters, and of the update
            tol = 4 * EPS32 * np.max(np.abs(old)) + 1e-4 * np.max(np.abs(u))
            assert np.max(np.abs(got - old - u)) <= tol, f"{what} at step {t}"
    assert clipped["theta"] >= 3 and clipped["v"] >= 3, clipped  # clipping really acted
    n_instants = sum(pseudo_gradients(b, a)[2] > 0 for b, a in pairs)
    assert sum(clipped.values()) < 2 * n_instants  # ... and not at every step


def test_adam_equals_numpy_adam_and_its_first_step_is_beta_sign():
    """'adam:b1:b2:eps' on g = -S: a numpy Adam (m, v, bias correction) over the update instants
    matches every step; its first step is +beta sign(S) where |S| >> eps."""
    env = TinyEnv(stop_prob=0.1)
    b1, b2, eps = 0.8, 0.95, 1e-6
    cfg = dataclasses.replace(tiny_config(l=2, num_envs=6, beta_theta=1e-2, beta_v=3e-2),
                              actor_opt=f"adam:{b1}:{b2}:{eps}", critic_opt=f"clip:1.0,adam:b1={b1}")
    trainer, pairs = _step_through(cfg, env, 25)
    state = {w: dict(m=0.0, v=0.0, k=0) for w in ("theta", "v")}
    first_checked = False
    for t, (before, after) in enumerate(pairs):
        s_t, s_v, n = pseudo_gradients(before, after)
        for what, g, beta, (bb1, bb2, ee) in (("theta", -s_t, cfg.beta_theta, (b1, b2, eps)),
                                              ("v", -clip(s_v, 1.0), cfg.beta_v, (b1, 0.999, 1e-8))):
            old, got = flat(getattr(before, what)), flat(getattr(after, what))
            if n == 0:
                np.testing.assert_array_equal(got, old)
                continue
            st = state[what]
            st["k"] += 1
            st["m"] = bb1 * st["m"] + (1 - bb1) * g
            st["v"] = bb2 * st["v"] + (1 - bb2) * g * g
            mh, vh = st["m"] / (1 - bb1 ** st["k"]), st["v"] / (1 - bb2 ** st["k"])
            u = -beta * mh / (np.sqrt(vh) + ee)
            tol = 4 * EPS32 * np.max(np.abs(old)) + 1e-3 * np.max(np.abs(u))
            assert np.max(np.abs(got - old - u)) <= tol, f"{what} at step {t}"
            if what == "theta" and st["k"] == 1:
                big = np.abs(g) > 1e3 * ee
                assert big.sum() > 10
                np.testing.assert_allclose((got - old)[big], beta * np.sign(-g[big]), rtol=1e-3,
                                           atol=4 * EPS32 * np.max(np.abs(old)))
                first_checked = True
    assert first_checked and state["theta"]["k"] >= 5
    ts = pairs[-1][1]
    assert int(ts.opt_theta.count) == state["theta"]["k"]  # the optimizer steps at update instants only
    mu = adam_state(ts.opt_theta).mu  # Adam's first moment, carried in the training state
    np.testing.assert_allclose(flat(mu), state["theta"]["m"], rtol=1e-3, atol=1e-7)


def test_step_size_of_a_chain_stays_traced():
    """A sweep over beta is still one program with any chain: beta from Hyper, no recompile."""
    env = TinyEnv(stop_prob=0.1)
    cfg = dataclasses.replace(tiny_config(l=2, num_envs=2, chunk_steps=20), actor_opt="clip:1,adam",
                              critic_opt="sgd,clip:0.1")
    trainer = make_train(cfg, env)
    chunk = jax.jit(trainer.chunk)
    ts0 = jax.jit(trainer.init)(jax.random.key(2))
    ref, _ = chunk(ts0)
    ts, _ = chunk(ts0.replace(hyper=ts0.hyper._replace(beta_theta=jnp.float32(0.0))))
    assert chunk._cache_size() == 1
    np.testing.assert_array_equal(flat(ts.theta), flat(ts0.theta))
    assert not np.allclose(flat(ref.theta), flat(ts0.theta))


# --------------------------------------------------------------------------- identity and checkpoints

#: The tiny Half-Cheetah trainer of tests/test_checkpoint.py, with a stateful chain on both networks.
CFG = options.build(TrainConfig, num_envs=4, chunk_steps=5, hidden_actor=8, hidden_critic=8, steps=15, seed=0, l=2, delta=1,
                  actor_opt="clip:5,adam:b1=0.8", critic_opt="adam,clip:0.5", beta_theta=1e-3, beta_v=1e-3)


def _host(x) -> np.ndarray:
    if jnp.issubdtype(jnp.asarray(x).dtype, jax.dtypes.prng_key):
        x = jax.random.key_data(x)
    return np.asarray(x)


def _same(a, b) -> bool:
    """Bit-identical pytrees (structure, dtypes, values; PRNG keys through their data)."""
    la, ta = jax.tree_util.tree_flatten(jax.tree.map(_host, a))
    lb, tb = jax.tree_util.tree_flatten(jax.tree.map(_host, b))
    return ta == tb and all(np.asarray(x).dtype == np.asarray(y).dtype and np.asarray(x).tobytes() ==
                            np.asarray(y).tobytes() for x, y in zip(la, lb))


@pytest.mark.slow  # ~60 s cold; by default test_checkpoint checks the optimizer state is saved and a resume equals the uninterrupted run
def test_checkpoint_carries_adam_state_and_resume_equals_uninterrupted(tmp_path):
    trainer = make_train(CFG)
    chunk = jax.jit(trainer.chunk)
    states = [jax.device_put(jax.jit(trainer.init)(jax.random.PRNGKey(0)))]
    for _ in range(3):
        states.append(chunk(states[-1])[0])
    assert int(states[1].opt_theta.count) > 0
    assert np.max(np.abs(flat(adam_state(states[1].opt_v).nu))) > 0  # the moments are not trivial
    run = tmp_path / "run"
    checkpoint.save(run, states[1], trainer.config)
    layout = checkpoint.load_metadata(run)["state_layout"]
    assert any(".mu." in n or n.endswith(".mu") for n in layout if n.startswith("opt_theta."))
    assert any(".nu." in n or n.endswith(".nu") for n in layout if n.startswith("opt_v."))
    meta_cfg = checkpoint.load_config(run)
    assert meta_cfg.actor_opt == "clip:max_norm=5.0,adam:b1=0.8:b2=0.999:eps=1e-08"
    fresh = make_train(CFG)  # as in a new process
    ts = checkpoint.restore(run, fresh)
    assert _same(ts, states[1])
    c2 = jax.jit(fresh.chunk)
    ts, _ = c2(ts)
    ts, _ = c2(ts)
    assert _same(ts, states[3])
    # another chain is another run: its trainer refuses this checkpoint, naming the field
    other = make_train(dataclasses.replace(CFG, critic_opt="adam"))
    with pytest.raises(checkpoint.ForeignCheckpoint, match=r"critic_opt: checkpoint 'adam:b1=0.9:b2=0.999"
                                                          r":eps=1e-08,clip:max_norm=0.5' != trainer"):
        checkpoint.restore(run, other)


def _write_run_config(d, cfg: TrainConfig) -> None:
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps(options.flat(cfg.resolved()), indent=2) + "\n")


def test_resume_with_another_chain_is_refused(tmp_path, capsys):
    run = tmp_path / "run"
    _write_run_config(run, options.build(TrainConfig, num_envs=4, steps=10, actor_opt="clip:10,sgd"))
    before = sorted(p.name for p in run.iterdir())
    assert cli.main(["train", "--resume", "--out", str(run), "--actor-opt", "sgd", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--actor-opt 'sgd' (the run has 'clip:max_norm=10.0,sgd')" in err, err
    assert sorted(p.name for p in run.iterdir()) == before
    # the same chain in another spelling is the same run (the canonical form is compared)
    from nmrl.runs import resume
    resume.given_changes(checkpoint.load_run_config(run), {"actor_opt": "clip:max_norm=10,sgd"}, run)


def test_sweep_resume_with_another_chain_is_refused(tmp_path, capsys):
    out = tmp_path / "sweep"
    out.mkdir()
    base = options.build(TrainConfig, num_envs=4, trials=10, critic_opt="adam").resolved()
    (out / "sweep.json").write_text(json.dumps({"ls": [1, 10], "seeds": 1, "first": [],
                                                "base": options.flat(base)}))
    assert cli.main(["sweep", "--resume", "--l", "1", "--out", str(out), "--critic-opt", "clip:1,sgd",
                     "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--critic-opt 'clip:1,sgd' (the run has 'adam:b1=0.9:b2=0.999:eps=1e-08')" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["sweep.json"]
