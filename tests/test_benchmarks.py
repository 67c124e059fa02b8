"""The benchmark harness runs: every section of ``python -m benchmarks`` at its smallest setting.

``python -m benchmarks --smoke --only <section>`` is run as a user runs it (a subprocess from the
checkout), one section per test, for every name in ``benchmarks.__main__.SECTIONS``: a benchmark
that calls a function which has moved or changed fails here, not in the next long measurement.
The smoke setting times a few calls of tiny batches, so its numbers mean nothing and are not
checked; what is checked is that the harness exits 0, fills the section and reports no failure.

The ``baseline`` section needs Brax: without it the section says so and the test is skipped; with
it, Brax's PPO compiles for minutes, so that case is marked ``slow``.
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.__main__ import SECTIONS, errors_in  # noqa: E402

SLOW = {"baseline"}  # Brax PPO's compile alone takes minutes


def _params():
    return [pytest.param(s, marks=pytest.mark.slow) if s in SLOW else s for s in SECTIONS]


@pytest.mark.parametrize("section", _params())
def test_section_runs_at_smoke_size(section, tmp_path):
    out = tmp_path / "smoke.json"
    p = subprocess.run([sys.executable, "-m", "benchmarks", "--smoke", "--only", section, "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, f"python -m benchmarks --smoke --only {section}: exit {p.returncode}\n{p.stderr[-3000:]}"
    res = json.loads(out.read_text())
    assert res["meta"]["size"] == "smoke" and res["meta"]["sections_run"] == [section]
    assert res["meta"]["failed"] == []
    body = res[section]
    assert isinstance(body, dict) and body, f"section {section} is empty: {body!r}"
    if "skipped" in body:
        pytest.skip(f"{section}: {body['skipped']}")
    assert errors_in(body) == []
    assert not out.with_suffix(".png").exists()  # a smoke run draws no figure


def test_baseline_section_says_why_it_skips_without_brax():
    from benchmarks import bench_baseline
    from nmrl.paper import brax_env

    if brax_env.HAVE_BRAX:
        pytest.skip("Brax is installed: the section runs (test_section_runs_at_smoke_size[baseline], slow)")
    assert "Brax is not installed" in bench_baseline.run(True, smoke=True)["skipped"]


def test_errors_in_finds_every_failure_and_nothing_else():
    ok = {"runs": [{"control_steps_per_s": 1.0}], "failed": False, "note": "error-free"}
    assert errors_in(ok) == []
    bad = {"a": {"error": "timeout after 5 s"}, "runs": [{}, {"error": "exit status [1]"}], "failed": True}
    assert errors_in(bad) == [".a: timeout after 5 s", ".runs[1]: exit status [1]", ".: True"]


def test_unknown_section_is_refused_in_one_line():
    p = subprocess.run([sys.executable, "-m", "benchmarks", "--smoke", "--only", "nosuch"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert p.stderr.strip() == f"--only: unknown benchmark(s) ['nosuch']; choose from {','.join(SECTIONS)}"
