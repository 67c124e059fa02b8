"""Is the optax update bit-identical to the paper's hand-written rule?

Loads the learner of commit a849a9d (``--old``; its update theta += beta^theta * sum_e d_e z_e is
written by hand) next to the current nmrl.paper.learner, runs both on the same
configs and seeds, and compares theta, v and the per-environment state after every chunk, bit for
bit. Prints one line per case and exits 1 if any case differs.

Cases: the paper's preset and networks (M^A = 100, M^C = 200, l = 10, Delta = 4) on Half-Cheetah
with N = 1 and N = 8, and the tiny test environment (tests/tiny_env.py) with large step sizes, l = 3,
N = 1 and N = 8. Chunks of 25 steps (each case compiles two programs; ~2-4 min on 2 cores).

    PYTHONPATH=. python scripts/lab/check_optax_update.py [--old a849a9d] [--chunks 4]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import pathlib
import subprocess
import sys
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
ROOT = pathlib.Path(__file__).resolve().parents[2]

import jax  # noqa: E402
import numpy as np  # noqa: E402

from nmrl.paper import learner  # noqa: E402


def _tiny_env():
    """tests/tiny_env.py (the test suite's small environment), loaded from its file."""
    spec = importlib.util.spec_from_file_location("tiny_env", ROOT / "tests" / "tiny_env.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.TinyEnv


TinyEnv = _tiny_env()


def load_old(commit: str):
    src = subprocess.run(["git", "show", f"{commit}:nmrl/learner.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    # that commit's nmrl is one flat folder; the modules it imports live in nmrl/paper/
    src = src.replace("from nmrl import networks, noise", "from nmrl.paper import networks, noise")
    src = src.replace("from nmrl.env import", "from nmrl.paper.env import")
    path = pathlib.Path(tempfile.mkdtemp()) / "learner_old.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("nmrl_learner_old", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look the module up
    spec.loader.exec_module(mod)
    return mod


def run(mod, kw: dict, env, chunks: int, seed: int):
    tr = mod.make_train(mod.TrainConfig(**kw), env)
    init, chunk = jax.jit(tr.init), jax.jit(tr.chunk)
    ts = init(jax.random.PRNGKey(seed))
    out = []
    for _ in range(chunks):
        ts, m = chunk(ts)
        out.append(jax.device_get((ts.theta, ts.v, ts.slots, m["periods_in_chunk"])))
    return out


def compare(a, b) -> tuple[bool, float]:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    same = len(la) == len(lb) and all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(la, lb))
    diff = max((float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64))))
                for x, y in zip(la, lb) if np.asarray(x).size and np.issubdtype(np.asarray(x).dtype, np.floating)),
               default=0.0)
    return same, diff


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--old", default="a849a9d")
    p.add_argument("--chunks", type=int, default=4)
    a = p.parse_args(argv)
    old = load_old(a.old)
    tiny = dict(hidden_actor=5, hidden_critic=6, beta_theta=0.02, beta_v=0.05, gamma=0.95, l=3, delta=1)
    cases = [
        ("halfcheetah paper N=1", dict(num_envs=1, chunk_steps=25), None),
        ("halfcheetah paper N=8", dict(num_envs=8, chunk_steps=25), None),
        ("tiny env N=1", dict(tiny, num_envs=1, chunk_steps=25), TinyEnv(stop_prob=0.05)),
        ("tiny env N=8", dict(tiny, num_envs=8, chunk_steps=25), TinyEnv(stop_prob=0.05)),
    ]
    bad = 0
    for name, kw, env in cases:
        r_old = run(old, kw, env, a.chunks, seed=1)
        r_new = run(learner, kw, env, a.chunks, seed=1)
        res = [(compare(o[0], n[0]), compare(o[1], n[1]), compare(o[2], n[2])) for o, n in zip(r_old, r_new)]
        identical = all(t[0] and v[0] and s[0] for t, v, s in res)
        worst = max(max(t[1], v[1], s[1]) for t, v, s in res)
        moved = max(compare(r_new[0][0], r_new[-1][0])[1], compare(r_new[0][1], r_new[-1][1])[1])
        periods = sum(int(np.sum(o[3])) for o in r_old)
        print(f"{name}: {a.chunks} chunks of {kw['chunk_steps']} steps, {periods} periods learned; theta, v, "
              f"slots {'bit-identical' if identical else 'DIFFER'} after every chunk (max |diff| {worst:.3g}; "
              f"parameters moved by up to {moved:.3g} between the first and last chunk)", flush=True)
        bad += not identical
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
