"""Writes tests/data/schema1_sgd_run/: a tiny run saved by the code of commit a849a9d, whose update
does not go through optax: its TrainState has no optimizer state.

Two checkpoints of one uninterrupted run, at step 5 and step 10, and the compact continuation state
(compact.npz) of step 5 (chunks of 5 control steps, 2
environments, 4 hidden units, l = 2, Delta = 1, large step sizes so that theta and v move visibly).
tests/test_checkpoint.py::test_restore_checkpoint_without_optimizer_state restores step 5 with the
current code (a fresh optimizer state), runs one chunk and compares with step 10.

Kept for the record; running it again with a newer nmrl writes the newer layout.
Run: ``PYTHONPATH=. python tests/data/make_schema1_sgd_checkpoint.py``
"""

import os
import pathlib
import shutil

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

from nmrl import checkpoint  # noqa: E402
from nmrl.learner import TrainConfig, make_train  # noqa: E402

OUT = pathlib.Path(__file__).resolve().parent / "schema1_sgd_run"
CFG = TrainConfig(num_envs=2, chunk_steps=5, hidden_actor=4, hidden_critic=4, steps=10, seed=0, l=2,
                  delta=1, beta_theta=0.01, beta_v=0.05)

if __name__ == "__main__":
    shutil.rmtree(OUT, ignore_errors=True)
    trainer = make_train(CFG)
    chunk = jax.jit(trainer.chunk)
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(CFG.budget.seed))
    for _ in range(2):
        ts, m = chunk(ts)
        checkpoint.save(OUT, ts, trainer.config, keep=2, extra={"note": "schema-1 layout, no optimizer state"})
        if int(ts.step) == 5:
            checkpoint.save_compact(OUT, ts, trainer.config)
        print(int(ts.step), float(m["theta_norm"]), float(m["v_norm"]), int(m["periods_in_chunk"]))
