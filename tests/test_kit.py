"""The study kit (nmrl/experiments/kit.py, kit_progress.py): cells run as sweeps, resumed, seeded from a
published copy, scored, published, stopped by a signal; where each cell stands."""

from __future__ import annotations

import csv
import dataclasses
import json

import pytest

from nmrl.experiments import kit, kit_progress
from nmrl.runs import store

TINY = {"num_envs": 4, "batch_size": 4, "num_minibatches": 1, "epochs": 1, "value_layers": 1, "value_width": 8,
        "policy_layers": 1, "policy_width": 8, "physics": "c"}


def _tiny_study(tmp_path):
    cell = kit.Cell("screen/a", "ppo", TINY, steps=20, vary=("sigma", (0.5, 1.0)), seeds=1, seed0=7,
                    run_options={"devices": "1"})
    return kit.Study("tiny", (cell,), kit.Endpoint(seconds=0.2, rollouts=2, start_noise=0.05))


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_a_study_runs_scores_publishes_and_continues_from_its_published_copy(tmp_path, monkeypatch):
    study = _tiny_study(tmp_path)
    out = tmp_path / "out"
    rows = kit.run(study, out)
    assert [(r["point"], r["seed"], r["value"], r["steps"]) for r in rows] == \
        [("sigma0.5_s7", 7, 0.5, 20), ("sigma1_s7", 7, 1.0, 20)]
    for r in rows:
        e = json.loads((out / "screen/a/points" / r["point"] / kit.ENDPOINT).read_text())
        assert e["step"] == 20 and len(e["rollouts"]) == 2 and r["det_reward_per_s"] == e["reward_per_s"]
    assert [x["point"] for x in _rows(out / kit.ROWS)] == ["sigma0.5_s7", "sigma1_s7"]
    # a second run has nothing to do: it starts no sweep and scores nothing again
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob(kit.ENDPOINT)}
    started = []
    monkeypatch.setattr(kit, "_sweep", lambda argv: started.append(argv) or 0)
    kit.run(study, out)
    assert started == []
    assert {p: p.stat().st_mtime_ns for p in out.rglob(kit.ENDPOINT)} == stamp
    monkeypatch.undo()
    # published: no full checkpoints; a fresh directory continues from it to a larger budget
    pub = tmp_path / "pub"
    kit.publish(study, out, pub)
    assert not list(pub.rglob("checkpoints")) and (pub / kit.ROWS).exists()
    # a fresh directory seeded from it at the same budget has nothing to do: no sweep starts
    monkeypatch.setattr(kit, "_sweep", lambda argv: started.append(argv) or 0)
    assert [r["steps"] for r in kit.run(study, tmp_path / "same", published=pub)] == [20, 20]
    assert (tmp_path / "same/screen/a/results.csv").is_file()
    # nor where the cell's results.csv is gone (a resume would have nothing to do and not write it)
    (tmp_path / "same/screen/a/results.csv").unlink()
    assert [r["steps"] for r in kit.run(study, tmp_path / "same", published=pub)] == [20, 20]
    assert started == []
    monkeypatch.undo()
    longer = dataclasses.replace(study, cells=(dataclasses.replace(study.cells[0], steps=40),))
    rows2 = kit.run(longer, tmp_path / "fresh", published=pub)
    assert [r["steps"] for r in rows2] == [40, 40]
    first = [json.loads(line) for line in (tmp_path / "fresh/screen/a/points/sigma0.5_s7/metrics.jsonl").open()]
    assert [m["step"] for m in first] == [20, 40]  # the published chunk kept, one more trained


def test_a_cell_is_at_its_budget_when_every_point_is_saved_there_or_diverged(tmp_path):
    """The kit skips a cell's resume only when the sweep would have nothing to do: every point's
    saved counter at the budget (a run of 20 steps is not at a budget of 40), or the point frozen by a
    diverged chunk; a missing state or point, or a damaged one, leaves it to the resume. A missing
    results.csv does not: the resume would have nothing to do and would not write it."""
    import shutil

    study = _tiny_study(tmp_path)
    kit.run(study, tmp_path / "out")
    d = tmp_path / "out" / "screen/a"
    cell = study.cells[0]
    longer = dataclasses.replace(cell, steps=40)
    assert kit.at_budget(cell, d) and not kit.at_budget(longer, d)
    a, b = (d / "points" / n for n in ("sigma0.5_s7", "sigma1_s7"))
    with open(a / "metrics.jsonl", "a") as fh:  # a diverged chunk after its last save: frozen at 20
        fh.write(json.dumps({"step": 40, "trials": 0, "diverged": True}) + "\n")
    assert not kit.at_budget(longer, d)  # b can still train to 40
    with open(b / "metrics.jsonl", "a") as fh:
        fh.write(json.dumps({"step": 40, "trials": 0, "diverged": False, "policy_norm": float("nan")}) + "\n")
    assert kit.at_budget(longer, d)  # both frozen
    assert kit.at_budget(cell, d)
    (b / "compact.npz").write_bytes((b / "compact.npz").read_bytes()[:-100])  # truncated, but b is frozen
    assert kit.at_budget(cell, d)
    (b / "metrics.jsonl").write_text((b / "metrics.jsonl").read_text().splitlines()[0] + "\n")
    assert not kit.at_budget(cell, d)  # b not frozen now, and its state unreadable
    shutil.copy2(a / "compact.npz", b / "compact.npz")
    assert kit.at_budget(cell, d)
    shutil.rmtree(b)
    assert not kit.at_budget(cell, d)  # a point of the sweep.json without files
    shutil.copytree(a, b)
    (d / "results.csv").unlink()
    assert kit.at_budget(cell, d)
    assert not kit.at_budget(dataclasses.replace(cell, steps=None), d)


def test_progress_reads_each_cells_chunks_and_time_left_from_its_files(tmp_path):
    """The least advanced point sets a cell's steps; the median wall time of its last 10 chunks prices
    the chunks left (rounded up to whole chunks); a diverged point counts as done; a point before its first
    saved chunk is at step 0, priced by another point's chunks if one has saved any; a cell without
    points has only its budget."""
    def point(cell, name, walls, chunk=10, diverged_at=None):
        d = tmp_path / cell / "points" / name
        d.mkdir(parents=True)
        (d / "config.json").write_text("{}")
        rows = [{"step": chunk * (i + 1), "trials": 0, "diverged": i == diverged_at, "wall_s": w}
                for i, w in enumerate(walls)]
        if rows:
            (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))

    point("a", "p0", [5.0, 7.0])
    point("a", "p1", [5.0, 7.0])
    point("b", "p0", [4.0, 8.0, 6.0])  # 30 of 45 steps: 2 chunks left (the last one partial)
    point("b", "p1", [4.0, 8.0, 6.0, 9.0])
    point("c", "p0", [3.0], diverged_at=0)
    point("c", "p1", [3.0, 5.0, 7.0])
    (tmp_path / "d").mkdir()
    point("e", "p0", [4.0, 6.0])
    point("e", "p1", [])  # 0 of 40 steps, priced by p0's chunks: 4 chunks of 5 s
    point("f", "p0", [])
    point("g", "p0", [100.0, 90.0] + [5.0, 7.0] * 5)  # two loaded chunks, then ten at the recent pace
    cells = tuple(kit.Cell(n, seeds=2, steps=b)
                  for n, b in (("a", 20), ("b", 45), ("c", 40), ("d", 20), ("e", 40), ("f", 40), ("g", 150)))
    rows = kit_progress.progress(kit.Study("t", cells, endpoint=None), tmp_path)
    got = {r["cell"]: r for r in rows}
    assert [got["a"][k] for k in ("points", "steps", "budget", "chunks", "s_per_chunk", "remaining_s")] == \
        [2, 20, 20, 2, 6.0, 0]
    assert [got["b"][k] for k in ("steps", "chunks", "s_per_chunk", "remaining_s")] == [30, 3, 6.0, 12]
    assert [got["c"][k] for k in ("steps", "chunks", "s_per_chunk", "remaining_s")] == [30, 3, 5.0, 5]
    assert got["d"]["budget"] == 20 and all(got["d"][k] == "" for k in ("points", "steps", "remaining_s"))
    assert [got["e"][k] for k in ("points", "steps", "chunks", "s_per_chunk", "remaining_s")] == [2, 0, 0, 5.0, 20]
    assert [got["f"][k] for k in ("points", "steps", "chunks", "s_per_chunk", "remaining_s")] == [1, 0, 0, "", ""]
    # the median of the last 10 chunks (5 and 7, five each), not the mean of all 12 (19.2)
    assert [got["g"][k] for k in ("steps", "chunks", "s_per_chunk", "remaining_s")] == [120, 12, 6.0, 18]
    assert kit_progress.progress_text(rows).splitlines()[-1] == (
        "0.0 h of wall time left in the started cells at their recent chunk times (1 started without a timed "
        "chunk, not counted); 1 cell(s) known but not started")


def test_a_row_holds_the_runs_endpoints_from_its_files(tmp_path):
    """Each row from the point's files, computed here by hand: the exploring reward and forward speed
    of the last chunk, the reward's mean over the chunks, the deterministic endpoint only where it
    scored the newest (or, diverged, the last good) policy."""
    cell = tmp_path / "c"
    (cell / "points").mkdir(parents=True)
    (cell / "sweep.json").write_text(json.dumps({"field": "sigma"}))

    def point(name, metrics, endpoint=None):
        d = cell / "points" / name
        d.mkdir()
        (d / "config.json").write_text(json.dumps({"seed": 3, "sigma": 0.4, "control_dt": 0.0025, "steps": 20}))
        (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in metrics))
        if endpoint is not None:
            (d / "endpoint.json").write_text(json.dumps(endpoint))

    point("fresh", [{"step": 10, "avg_reward": -1.0, "forward_speed": 0.5},
                    {"step": 20, "avg_reward": 0.6, "forward_speed": 1.25}],
          {"step": 20, "reward_per_s": 42.0, "forward_speed": [1.0, 2.0, 3.0]})
    point("stale", [{"step": 10, "avg_reward": 0.2, "forward_speed": 0.1}],
          {"step": 5, "reward_per_s": 1.0, "forward_speed": [9.0]})
    rows = {r["point"]: r for r in kit.rows(kit.Study("t", (kit.Cell("c"),), endpoint=None), tmp_path)}
    f = rows["fresh"]
    assert (f["seed"], f["field"], f["value"], f["steps"], f["budget"], f["diverged"]) == (3, "sigma", 0.4, 20, 20, False)
    assert f["avg_reward_per_s"] == pytest.approx(0.6 / 0.02) and f["auc_reward_per_s"] == pytest.approx(-0.2 / 0.02)
    assert (f["det_reward_per_s"], f["forward_speed"], f["det_forward_speed"]) == (42.0, 1.25, 2.0)
    st = rows["stale"]
    assert (st["forward_speed"], st["det_reward_per_s"], st["det_forward_speed"]) == (0.1, "", "")


def test_a_cell_of_listed_points_refuses_a_sweep_of_other_points(tmp_path):
    """A cell's listed points are the ones its sweep.json records; other settings' points are refused
    before any sweep runs (the same points, as JSON gives them back, continue)."""
    d = tmp_path / "c"
    d.mkdir()
    (d / "sweep.json").write_text(json.dumps({"points": [{"name": "a", "l": 1, "beta_theta": 1e-05, "seed": 0}]}))
    study = kit.Study(name="t", cells=(), endpoint=None)
    other = kit.Cell("c", steps=10, points=({"name": "a", "l": 2, "beta_theta": 1e-05, "seed": 0},))
    with pytest.raises(kit.StudyError, match="other points"):
        kit.run_cell(study, other, tmp_path)
    assert [p.name for p in d.iterdir()] == ["sweep.json"]


_CTRL_C_STUDY = r'''
import pathlib, sys
from nmrl.experiments import kit

FAKE_SWEEP = """
import pathlib, signal, sys, time
out = pathlib.Path(sys.argv[sys.argv.index("--out") + 1])
out.mkdir(parents=True, exist_ok=True)
def save_and_stop(signum, frame):
    time.sleep(1.0)  # the sweep saves its points
    (out / "saved").write_text("yes")
    sys.exit(130)
signal.signal(signal.SIGINT, save_and_stop)
(out / "started").write_text("yes")
time.sleep(60)
"""
kit._nmrl = lambda: [sys.executable, "-c", FAKE_SWEEP]
study = kit.Study(name="t", cells=(kit.Cell("c", seeds=1),), endpoint=None)
try:
    kit.run_cell(study, study.cells[0], pathlib.Path(sys.argv[1]))
except kit.StudyStopped as e:
    print("stopped", e.status)
'''


def test_ctrl_c_lets_the_cells_sweep_save_before_the_study_stops(tmp_path):
    """A Ctrl-C signals the study and its running sweep together (one process group): the study
    waits while the sweep saves and exits, then stops with the sweep's status; it never kills it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    p = subprocess.Popen([sys.executable, "-c", _CTRL_C_STUDY, str(tmp_path)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while not (tmp_path / "c" / "started").exists():
        assert p.poll() is None and time.monotonic() < deadline, p.communicate()
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGINT)  # what the terminal sends on Ctrl-C
    out, err = p.communicate(timeout=60)
    assert (tmp_path / "c" / "saved").read_text() == "yes", err
    assert out.strip() == "stopped 130", err


_RECORDING_SWEEP = """
import json, pathlib, sys
out = pathlib.Path(sys.argv[sys.argv.index("--out") + 1])
out.mkdir(parents=True, exist_ok=True)
with open(out.parent / "argv.jsonl", "a") as fh:
    fh.write(json.dumps(sys.argv[1:]) + "\\n")
(out / "sweep.json").write_text("{}")
"""


def test_a_cells_run_options_are_given_on_its_start_and_every_resume(tmp_path, monkeypatch):
    import sys

    monkeypatch.setattr(kit, "_nmrl", lambda: [sys.executable, "-c", _RECORDING_SWEEP])
    study = kit.Study(name="t", cells=(), endpoint=None)
    cell = kit.Cell("c", seeds=2, steps=10, run_options={"group": 2})
    kit.run_cell(study, cell, tmp_path)  # starts it
    kit.run_cell(study, cell, tmp_path)  # resumes it
    start, resume = [json.loads(line) for line in (tmp_path / "argv.jsonl").read_text().splitlines()]
    assert start[:6] == ["sweep", "--learner", "ac", "--steps", "10", "--seeds"] and "--resume" not in start
    assert resume[:4] == ["sweep", "--resume", "--steps", "10"]
    for argv in (start, resume):
        assert argv[argv.index("--group") + 1] == "2" and argv[-2] == "--out"
        assert argv.index("--quiet") < argv.index("--group")  # after the study's own run options


_POINT_SWEEP = """
import json, pathlib, sys
out = pathlib.Path(sys.argv[sys.argv.index("--out") + 1])
p = out / "points" / "s0"
p.mkdir(parents=True, exist_ok=True)
(out / "sweep.json").write_text("{}")
(p / "config.json").write_text(json.dumps({"seed": 0, "steps": 10, "control_dt": 0.02}))
(p / "metrics.jsonl").write_text(json.dumps({"step": 10, "avg_reward": 0.1, "diverged": False}) + "\\n")
"""


def test_each_measurement_runs_after_every_cell_on_the_rows_so_far(tmp_path, monkeypatch):
    """A measurement sees each finished cell's rows as soon as that cell has run (so a publish between
    cells holds it), in the study's order, and once more only when no cell ran."""
    import sys

    monkeypatch.setattr(kit, "_nmrl", lambda: [sys.executable, "-c", _POINT_SWEEP])
    calls: list[tuple[str, tuple[str, ...]]] = []

    def measure(name):
        return lambda out, rows: calls.append((name, tuple(r["cell"] for r in rows)))

    study = kit.Study(name="t", cells=(kit.Cell("a", steps=10), kit.Cell("b", steps=10)),
                      endpoint=None, measurements=(kit.Measurement("m1", measure("m1")),
                                                   kit.Measurement("m2", measure("m2"))))
    kit.run(study, tmp_path)
    assert calls == [("m1", ("a",)), ("m2", ("a",)), ("m1", ("a", "b")), ("m2", ("a", "b"))]
    calls.clear()
    kit.run(study, tmp_path, only=())  # no cell to run: the measurements run once on the rows as they are
    assert calls == [("m1", ("a", "b")), ("m2", ("a", "b"))]


def test_a_study_resumed_from_its_published_copy_continues_its_measurements(tmp_path, monkeypatch):
    """A measurement that continues its own file (one line per cell it measured, as the study's
    measurements keep their rows) measures on a fresh machine only what the published copy lacks:
    its file (and a folder measurement's) is seeded from the copy, never over one already there."""
    import sys

    monkeypatch.setattr(kit, "_nmrl", lambda: [sys.executable, "-c", _POINT_SWEEP])
    measured: list[str] = []

    def log(out, rows):
        f = out / "log.txt"
        have = f.read_text().split() if f.exists() else []
        for c in dict.fromkeys(r["cell"] for r in rows):
            if c not in have:
                measured.append(c)
                have.append(c)
        f.write_text("\n".join(have))

    def folder(out, rows):
        (out / "pics").mkdir(exist_ok=True)
        if not (out / "pics" / "made.txt").exists():
            measured.append("pics")
            (out / "pics" / "made.txt").write_text("x")

    cells = (kit.Cell("a", steps=10), kit.Cell("b", steps=10))
    study = kit.Study(name="t", cells=cells[:1], endpoint=None,
                      measurements=(kit.Measurement("log.txt", log), kit.Measurement("pics", folder)))
    kit.run(study, tmp_path / "first")
    assert measured == ["a", "pics"]
    kit.publish(study, tmp_path / "first", tmp_path / "pub")
    measured.clear()
    longer = dataclasses.replace(study, cells=cells)
    kit.run(longer, tmp_path / "fresh", published=tmp_path / "pub")
    assert measured == ["b"]  # a and the folder came with the copy
    assert (tmp_path / "fresh" / "log.txt").read_text().split() == ["a", "b"]
    (tmp_path / "own").mkdir()
    (tmp_path / "own" / "log.txt").write_text("z")  # a file already there is the run's own: kept
    measured.clear()
    kit.run(longer, tmp_path / "own", published=tmp_path / "pub")
    assert measured == ["a", "b"]
    assert (tmp_path / "own" / "log.txt").read_text().split() == ["z", "a", "b"]


def test_a_cell_the_rule_adds_runs_where_the_rule_puts_it(tmp_path, monkeypatch):
    """A rule lists x (once a's rows exist, and only while x has none, as an extension drops out while
    its runs go on) before c (from the start): the study runs a, x, c, not in the order it first knew
    them (a, c, x), and x keeps its place once the rule stops listing it."""
    import pathlib
    import sys

    monkeypatch.setattr(kit, "_nmrl", lambda: [sys.executable, "-c", _POINT_SWEEP])
    ran: list[str] = []
    sweep = kit._sweep
    monkeypatch.setattr(kit, "_sweep", lambda argv: ran.append(pathlib.Path(argv[argv.index("--out") + 1]).name)
                        or sweep(argv))

    def later(rows):
        have = {r["cell"] for r in rows}
        return [*([kit.Cell("x", steps=10)] if "a" in have and "x" not in have else []),
                kit.Cell("c", steps=10)]

    study = kit.Study(name="t", cells=(kit.Cell("a", steps=10),), endpoint=None, later=later)
    kit.run(study, tmp_path)
    assert ran == ["a", "x", "c"]
    assert [c.name for c in kit.all_cells(study, tmp_path)] == ["a", "x", "c"]


def test_table_prints_the_published_analysis_as_markdown(tmp_path, capsys):
    """``table`` reads analysis.csv as written (store.write_csv) and shows each estimate with its Welch
    and bootstrap intervals to 0.1 and the Holm p to 2 significant digits; without the file it stops
    with status 2 naming the folder, before printing any table."""
    from nmrl.experiments import kit_cli, thesis_ac

    rows = [{"family": "primary", "endpoint": "auc_reward_per_s", "contrast": "T1", "n": "8 8",
             "estimate": 117.0856, "lo": 64.4888, "hi": 169.6824, "boot_lo": 73.04, "boot_hi": 160.96,
             "p": 4.78e-4, "tost_p": 0.99, "p_holm": 0.0019748, "tost_p_holm": 1.0, "decision": "ahead"},
            {"family": "secondary", "endpoint": "auc_reward_per_s", "contrast": "T1", "n": "8 0",
             "decision": "pending"}]
    store.write_csv(tmp_path / kit.ANALYSIS, list(rows[0]), rows)
    assert thesis_ac.main(["table", "--dest", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| family | endpoint | contrast | n | estimate | bootstrap | p_holm | tost_p_holm | decision |"
    assert lines[2] == "| primary | auc_reward_per_s | T1 | 8 8 | 117.1 [64.5, 169.7] | [73.0, 161.0] | 0.002 | 1 | ahead |"
    assert lines[3] == "| secondary | auc_reward_per_s | T1 | 8 0 |  |  |  |  | pending |"
    with pytest.raises(SystemExit) as e:
        thesis_ac.main(["table", "--dest", str(tmp_path / "none")])
    assert e.value.code == 2 and str(tmp_path / "none") in capsys.readouterr().err


@pytest.mark.parametrize("steps, budget, diverged, final", [
    (156_500, 156_250, False, True),  # the last chunk of 500 steps passes a budget that is no multiple of it
    ("156500", "156250", "False", True),  # the same row read back from rows.csv
    (156_000, 156_250, False, False),
    (1_000, 156_250, "True", True),  # diverged: frozen at its last good policy
    (1_000, "", "False", False),  # a budget in trials: not known from the row
])
def test_a_row_is_final_at_or_past_its_budget_or_diverged(steps, budget, diverged, final):
    assert kit.ended({"steps": steps, "budget": budget, "diverged": diverged}) is final
