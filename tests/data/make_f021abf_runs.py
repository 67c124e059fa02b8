"""Writes tests/data/f021abf_train_run/ and tests/data/f021abf_sweep_run/: a tiny ``nmrl train`` run
and a tiny ``nmrl sweep`` run directory written by the code of commit f021abf (the flat, unlayered
package), and the metrics the same code writes when it runs them
on without interruption (``expected_*.jsonl``).

* ``f021abf_train_run``: ``nmrl train`` (2 environments, 4 hidden units, l = 2, Delta = 1, chunks of
  5 control steps, large step sizes so that theta and v move visibly), stopped after its first
  chunk: config.json, metrics.jsonl, checkpoints/5. ``expected_train_metrics.jsonl`` holds the
  metrics of the same run trained uninterrupted to step 10.
* ``f021abf_sweep_run``: ``nmrl sweep --l 1 2 --seeds 1`` with the same settings, one chunk:
  sweep.json, results.csv, points/l{1,2}_s0/{config.json, metrics.jsonl, checkpoints/5,
  compact.npz} (fig3.png is not kept: 60 kB that no test reads). ``expected_sweep_metrics.json``
  holds every point's metrics of the same sweep run uninterrupted to step 10.

tests/test_compat.py resumes both with the current code and compares with the expected metrics.

Run with the OLD code on the path, from the repository root of the new one::

    git worktree add --detach /tmp/old f021abf
    PYTHONPATH=/tmp/old .venv/bin/python tests/data/make_f021abf_runs.py /tmp/old

Kept for the record: running it with a newer nmrl writes that code's layout instead.
"""

import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
COMMON = ["--num-envs", "2", "--chunk-steps", "5", "--hidden-actor", "4", "--hidden-critic", "4",
          "--delta", "1", "--beta-theta", "0.01", "--beta-v", "0.05", "--devices", "1", "--quiet"]


def nmrl(old: pathlib.Path, *args: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(old), "JAX_PLATFORMS": "cpu"}
    code = "import sys; from nmrl.cli import main; sys.exit(main(sys.argv[1:]))"
    subprocess.run([sys.executable, "-c", code, *args], check=True, env=env, cwd=old)


def main(old: pathlib.Path) -> None:
    for name in ("f021abf_train_run", "f021abf_sweep_run"):
        shutil.rmtree(HERE / name, ignore_errors=True)
    train = HERE / "f021abf_train_run"
    nmrl(old, "train", "--l", "2", "--seed", "0", "--steps", "5", *COMMON, "--out", str(train))
    sweep = HERE / "f021abf_sweep_run"
    nmrl(old, "sweep", "--l", "1", "2", "--seeds", "1", "--steps", "5", *COMMON, "--out", str(sweep))
    (sweep / "fig3.png").unlink(missing_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        ref = pathlib.Path(tmp) / "train"
        nmrl(old, "train", "--l", "2", "--seed", "0", "--steps", "10", *COMMON, "--out", str(ref))
        shutil.copy(ref / "metrics.jsonl", HERE / "expected_train_metrics.jsonl")
        ref = pathlib.Path(tmp) / "sweep"
        nmrl(old, "sweep", "--l", "1", "2", "--seeds", "1", "--steps", "10", *COMMON, "--out", str(ref))
        rows = {p.name: [json.loads(x) for x in (p / "metrics.jsonl").read_text().splitlines() if x.strip()]
                for p in sorted((ref / "points").iterdir())}
        (HERE / "expected_sweep_metrics.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1]))
