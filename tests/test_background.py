"""scripts/run/background.sh on stand-in runs: the sweep on core 0 and PPO on core 1 while PPO has
seeds to run; the hand-off that moves the sweep to every core once PPO ends having finished every
seed; no hand-off once `stop` has begun; and `start` with PPO already done (runs/, or only the
published copy of a fresh clone) putting the sweep on every core and PPO nowhere.

The stand-ins are shell scripts in a copy of the layout, matched by process patterns unique to
this test, so the project's real long runs (if any are going) are never signalled."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
import time
import uuid

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("setsid") is None or shutil.which("pgrep") is None,
                                reason="needs setsid and pgrep (util-linux, procps)")


@pytest.fixture
def layout(tmp_path):
    tag = uuid.uuid4().hex[:12]
    sweep_pat, ppo_pat = f"standin-sweep-{tag}", f"standin-ppo-{tag}"
    run = tmp_path / "scripts" / "run"
    run.mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "run" / "background.sh", run / "background.sh")
    scripts = {
        # the sweep: says on which cores it was started, then runs until signalled
        "fig3_paper.sh": f'echo "sweep started CPUS=${{CPUS:-every}}"\nexec -a {sweep_pat} sleep 300\n',
        # PPO: finishes seed 0 (its budget 100 steps) at once when asked to, else runs on
        "baseline_ppo.sh": ("d=runs/baseline_ppo/ppo_s0; mkdir -p $d\n"
                            "echo '{\"num_timesteps\": 100}' > $d/config.json\n"
                            "if [ -e ppo_finishes ]; then echo '{\"step\": 120}' > $d/metrics.jsonl; exit 0; fi\n"
                            f"echo '{{\"step\": 40}}' > $d/metrics.jsonl; exec -a {ppo_pat} sleep 300\n"),
    }
    for name, body in scripts.items():
        (run / name).write_text("#!/usr/bin/env bash\n" + body)
        (run / name).chmod(0o755)
    fake_py = tmp_path / "python"  # this interpreter, with `import brax` answered yes
    fake_py.write_text(f'#!/usr/bin/env bash\nif [ "$*" = "-c import brax" ]; then exit 0; fi\n'
                       f'exec {sys.executable} "$@"\n')
    fake_py.chmod(0o755)
    bin_dir = tmp_path / "bin"  # two cores, whatever this machine (or this test's CPU affinity) has
    bin_dir.mkdir()
    (bin_dir / "nproc").write_text("#!/usr/bin/env bash\necho 2\n")
    (bin_dir / "nproc").chmod(0o755)
    env = {**os.environ, "SWEEP_PAT": sweep_pat, "PPO_PAT": ppo_pat, "PY": str(fake_py), "SEEDS": "0",
           "STOP_TIMEOUT": "20", "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    env.pop("CPUS", None)
    yield tmp_path, env
    for pat in (sweep_pat, ppo_pat):
        subprocess.run(["pkill", "-KILL", "-f", pat], check=False)


def _bg(root, env, cmd):
    p = subprocess.run(["bash", "scripts/run/background.sh", cmd], cwd=root, env=env, capture_output=True,
                       text=True, timeout=60)
    return p.stdout + p.stderr


def _sweep_starts(root, n, timeout=20.0):
    log = root / "runs" / "fig3_paper.log"
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        got = [x for x in log.read_text().splitlines() if x.startswith("sweep started")] if log.exists() else []
        if len(got) >= n:
            return got
        time.sleep(0.2)
    raise AssertionError(f"expected {n} sweep starts within {timeout} s; log: "
                         f"{log.read_text() if log.exists() else '(none)'}")


def _running(pat):
    return subprocess.run(["pgrep", "-f", pat], capture_output=True).returncode == 0


def test_ppo_running_keeps_the_sweep_on_core_0(layout):
    root, env = layout
    out = _bg(root, env, "start")
    assert "sweep on core 0" in out and "PPO baseline on core 1" in out
    assert _sweep_starts(root, 1) == ["sweep started CPUS=0"]
    time.sleep(1.0)
    assert _running(env["PPO_PAT"]) and _running(env["SWEEP_PAT"])
    assert _sweep_starts(root, 1) == ["sweep started CPUS=0"]  # no hand-off while PPO runs


def test_ppo_finishing_hands_every_core_to_the_sweep(layout):
    root, env = layout
    (root / "ppo_finishes").touch()
    _bg(root, env, "start")
    assert _sweep_starts(root, 2) == ["sweep started CPUS=0", "sweep started CPUS=every"]
    assert "moving the Fig. 3 sweep to every core" in (root / "runs" / "baseline_ppo.log").read_text()
    assert _running(env["SWEEP_PAT"])


def test_no_hand_off_once_stop_has_begun(layout):
    root, env = layout
    (root / "runs").mkdir()
    (root / "runs" / "background.stopping").touch()  # what `stop` leaves, as if it ran meanwhile
    # start clears the flag, so set it again right after: the PPO stand-in finishes a moment later
    (root / "ppo_finishes").touch()
    slow = root / "scripts" / "run" / "baseline_ppo.sh"
    slow.write_text(slow.read_text().replace("#!/usr/bin/env bash\n", "#!/usr/bin/env bash\nsleep 2\n"))
    _bg(root, env, "start")
    (root / "runs" / "background.stopping").touch()
    time.sleep(5.0)
    assert _sweep_starts(root, 1) == ["sweep started CPUS=0"]
    assert "moving" not in (root / "runs" / "baseline_ppo.log").read_text()


@pytest.mark.parametrize("where", ["runs", "results"])
def test_start_with_ppo_done_gives_the_sweep_every_core(layout, where):
    root, env = layout
    d = root / where / "baseline_ppo" / "ppo_s0"  # results/: a fresh clone of the published run
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps({"num_timesteps": 100}))
    (d / "metrics.jsonl").write_text('{"step": 60}\n{"step": 120}\n')
    out = _bg(root, env, "start")
    assert "sweep on every core" in out and "finished every seed" in out
    assert _sweep_starts(root, 1) == ["sweep started CPUS=every"]
    assert not _running(env["PPO_PAT"])


def test_status_gives_the_sweep_s_last_chunk_times(layout):
    """Per chunk, from the running totals in the log, of the newest process only (its compile line starts it)."""
    root, env = layout
    (root / "runs").mkdir()
    lines = ["compiled the sweep chunk in 80.0 s", "sweep: 24 points, 100 s", "  l2_s0  trials 1",
             "sweep: 24 points, 1,150 s", "stopped by signal 15",
             "compiled the sweep chunk in 83.2 s"] + [f"sweep: 24 points, {t:,} s" for t in (107, 230, 340)]
    (root / "runs" / "fig3_paper.log").write_text("\n".join(lines) + "\n")
    out = _bg(root, env, "status")
    assert "sweep: its last chunks took 107 123 110 s" in out
    assert "sweep: not running" in out and "ppo: not running" in out
