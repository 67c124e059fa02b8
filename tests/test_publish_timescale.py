"""The finer-delta study's publisher (nmrl/analysis/publish_timescale.py) against its committed records.

A study directory laid out as the study writes it (``grid/dt<δ>/points/<point>/metrics.jsonl`` and
the tables), rebuilt here from each published record, publishes to the record byte for byte: the
tables, every point's metrics and both figures; the Markdown tables carry the mean and scipy's t
interval of each arm's final rewards.
"""

from __future__ import annotations

import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats

from nmrl.analysis import publish_timescale as pub
from nmrl.runs.store import read_csv

REPO = pathlib.Path(__file__).resolve().parents[1]
RECORDS = [REPO / "results" / n for n in ("timescale", "timescale_cap", "timescale_cap300")]


def _files(d: pathlib.Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("record", RECORDS, ids=lambda p: p.name)
def test_a_study_directory_publishes_to_its_record_byte_for_byte(tmp_path, record):
    src = tmp_path / "study"
    for f in pub.TABLES:
        if (record / f).exists():
            (src / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(record / f, src / f)
    for m in (record / "metrics").glob("*/dt*/*.jsonl"):
        phase, dt = m.parts[-3], m.parts[-2]
        point = src / phase / dt / "points" / m.stem
        point.mkdir(parents=True)
        shutil.copy2(m, point / "metrics.jsonl")
    pub.publish(src, tmp_path / "published")
    assert _files(tmp_path / "published") == _files(record)


def test_the_tables_carry_each_arms_mean_and_t_interval():
    record = RECORDS[0]
    md = pub.tables(record)
    final = read_csv(record / "final.csv")
    for arm in ("stationary", "p0.2s"):
        v = np.array([float(r["reward_per_s"]) for r in final if r["arm"] == arm and float(r["dt"]) == 0.005])
        lo, hi = scipy.stats.t.interval(0.95, len(v) - 1, loc=v.mean(), scale=scipy.stats.sem(v))
        row = next(ln for ln in md.splitlines() if ln.startswith(f"| {arm} |"))
        assert f"{v.mean():+.1f} ± {(hi - lo) / 2:.1f} ({', '.join(f'{x:+.0f}' for x in v)})" in row.split(" | ")[3]


@pytest.mark.parametrize("args,needle", [(["{tmp}/none"], "DIR="), (["{tmp}/a", "{tmp}/b", "{tmp}/c"], "DIR=")])
def test_bad_directories_are_one_line_exit_2_nothing_written(tmp_path, args, needle):
    p = subprocess.run([sys.executable, "scripts/publish/publish_timescale.py",
                        *[a.replace("{tmp}", str(tmp_path)) for a in args]], cwd=REPO, capture_output=True,
                       text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and needle in lines[0] and "is invalid" in lines[0], p.stderr
    assert list(tmp_path.iterdir()) == []
