"""scripts/run/exploration_keep.sh on a stand-in study in a throwaway git repository: `watch` stops the
study, evaluates and publishes results/exploration and starts the study again, every interval, and
commits nothing (the repository's history is the caller's); a bad interval is refused with exit 2
before anything starts.

The stand-in study is a process matched by a pattern unique to this test, so the project's real
study (if one is going) is never signalled."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys
import time
import uuid

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(any(shutil.which(t) is None for t in ("setsid", "pgrep", "git")),
                                reason="needs setsid, pgrep (util-linux, procps) and git")


@pytest.fixture
def layout(tmp_path):
    tag = uuid.uuid4().hex[:12]
    pat = f"standin-study-{tag}"
    (tmp_path / "scripts" / "run").mkdir(parents=True)
    for f in ("run/exploration_keep.sh", "lower_priority.sh"):
        shutil.copy(REPO / "scripts" / f, tmp_path / "scripts" / f)
    study = tmp_path / "scripts" / "exploration_study.sh"  # says it started, then runs until signalled
    study.write_text(f'#!/usr/bin/env bash\nmkdir -p runs/exploration\necho "{{}}" > runs/exploration/study.json\n'
                     f'echo "study started"\nexec -a {pat} sleep 300\n')
    study.chmod(0o755)
    nmrl = tmp_path / "nmrl"  # the evaluation: records its arguments
    nmrl.write_text('#!/usr/bin/env bash\necho "$*" >> calls\n')
    nmrl.chmod(0o755)
    py = tmp_path / "python"  # the publisher: one more row in results.csv per call
    py.write_text('#!/usr/bin/env bash\nif [ "$1" = scripts/publish_exploration.py ]; then\n'
                  '  mkdir -p results/exploration; f=results/exploration/results.csv\n'
                  '  [ -f $f ] || echo "seed" > $f; echo "$(wc -l < $f)" >> $f; echo publish >> calls; exit 0\nfi\n'
                  f'exec {sys.executable} "$@"\n')
    py.chmod(0o755)
    (tmp_path / "other.txt").write_text("a file the loop must not commit\n")
    env = {**os.environ, "STUDY_PAT": pat, "PY": str(py), "NMRL": str(nmrl), "STOP_TIMEOUT": "20",
           "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t"}
    git = ["git", "-c", "init.defaultBranch=main"]
    subprocess.run(git + ["init", "-q"], cwd=tmp_path, check=True)
    subprocess.run(["git", "add", "scripts", "other.txt"], cwd=tmp_path, check=True, env=env)
    subprocess.run(["git", "commit", "-qm", "start"], cwd=tmp_path, check=True, env=env)
    (tmp_path / "other.txt").write_text("changed\n")
    yield tmp_path, env, pat, f"keep-{tag}"
    subprocess.run(["pkill", "-KILL", "-f", f"exploration_keep.sh watch.*keep-{tag}"], check=False)
    subprocess.run(["pkill", "-KILL", "-f", pat], check=False)


def _wait(cond, timeout, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return
        time.sleep(0.2)
    raise AssertionError(f"not within {timeout} s: {what}")


def _commits(root) -> int:
    out = subprocess.run(["git", "rev-list", "--count", "HEAD"], cwd=root, capture_output=True, text=True)
    return int(out.stdout.strip())


def test_watch_publishes_and_restarts_without_committing(layout):
    root, env, pat, tag = layout
    env = {**env, "INTERVAL_S": "1"}
    # the tag in the command line lets the fixture end this loop and no other
    watch = subprocess.Popen(["bash", "scripts/run/exploration_keep.sh", "watch", "5", tag], cwd=root, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    calls = root / "calls"
    try:
        _wait(lambda: calls.exists() and calls.read_text().splitlines().count("publish") >= 2, 120,
              "two publishes")  # ~6 s on a quiet machine; a loaded one takes ~1 min
        _wait(lambda: (root / "runs" / "exploration.log").read_text().count("study started") >= 3, 60,
              "the study started again after each publish")
    finally:
        watch.kill()
    out = watch.stdout.read().decode()
    assert "published results/exploration (2 runs in results.csv)" in out  # counts the published rows
    assert calls.read_text().splitlines()[:2] == ["explore-study --out runs/exploration --phases eval --quiet",
                                                   "publish"]
    assert _commits(root) == 1  # the fixture's own commit: the loop commits nothing
    status = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True).stdout
    assert "?? results/" in status and " M other.txt" in status


@pytest.mark.parametrize("bad", ["2", "ten", "-5"])
def test_watch_refuses_a_bad_interval(layout, bad):
    root, env, pat, _ = layout
    p = subprocess.run(["bash", "scripts/run/exploration_keep.sh", "watch", bad], cwd=root, env=env,
                       capture_output=True, text=True, timeout=30)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [f"watch: MIN={bad} is invalid: a whole number of minutes >= 5"]
    assert not (root / "runs").exists()
    assert subprocess.run(["pgrep", "-f", pat], capture_output=True).returncode != 0
