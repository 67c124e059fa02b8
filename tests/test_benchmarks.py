"""The benchmark harness runs: every section of ``python -m benchmarks`` at its smallest setting.

First, in seconds: every name a benchmark takes from nmrl (``from nmrl.x import y``, ``module.attr``)
exists, so a function that moves breaks this test and not the next measurement.

``python -m benchmarks --smoke --only <section>`` is run as a user runs it (a subprocess from the
checkout), one section per test, for every name in ``benchmarks.__main__.SECTIONS``: a benchmark
that calls a function which has moved or changed fails here, not in the next long measurement.
The smoke setting times a few calls of tiny batches, so its numbers mean nothing and are not
checked; what is checked is that the harness exits 0, fills the section and reports no failure.

The sections that compile MuJoCo-MJX programs (the environment, a training chunk, ``nmrl train``
processes) take minutes on a cold compile cache even at the smoke size -- one MJX compile is 20-90 s
on the 2-core machine, depending on its load -- so their smoke runs are marked ``slow``
(``pytest -m slow tests/test_benchmarks.py``); the name check above covers them in the default suite.
The ``baseline`` section needs Brax: without it the section says so and the test is skipped.
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

#: sections whose smoke run compiles MJX or Brax programs (minutes on a cold cache); every other
#: section, present or added later, runs in the default suite
SLOW = {"env", "learning", "sweep", "scaling", "distributed", "baseline", "ppo", "physics_c"}
BENCH = ROOT / "benchmarks"


def _nmrl_references(path: pathlib.Path) -> list[tuple[str, str, int]]:
    """``(module, name, line)`` for every name a benchmark file takes from an nmrl module: the names of
    ``from nmrl.m import name`` and the attributes ``alias.name`` of an imported nmrl module ``alias``."""
    import ast

    tree = ast.parse(path.read_text())
    aliases, refs = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("nmrl"):
                    aliases[a.asname or a.name] = a.name
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("nmrl"):
            for a in node.names:
                refs.append((node.module, a.name, node.lineno))
                aliases[a.asname or a.name] = f"{node.module}.{a.name}"  # a submodule, or not a module at all
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            refs.append((aliases[node.value.id], node.attr, node.lineno))
    return refs


def _resolves(module: str, name: str) -> bool:
    import importlib

    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError:
        return False  # ``alias.attr`` where alias is a class or function: checked as its own import
    if hasattr(mod, name):
        return True
    try:
        importlib.import_module(f"{module}.{name}")
        return True
    except ModuleNotFoundError:
        return False


@pytest.mark.parametrize("path", sorted(BENCH.glob("*.py")), ids=lambda p: p.name)
def test_every_name_a_benchmark_takes_from_nmrl_exists(path):
    import importlib

    missing = []
    for module, name, line in _nmrl_references(path):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError:
            parent, _, attr = module.rpartition(".")
            if not _resolves(parent, attr):
                missing.append(f"{path.name}:{line}: {module}")
            continue  # a class or function (alias.attr on it is not a module attribute)
        if not _resolves(module, name):
            missing.append(f"{path.name}:{line}: {module}.{name}")
    assert missing == [], missing


def test_the_reference_check_sees_a_moved_function(tmp_path):
    bad = tmp_path / "bench_bad.py"
    bad.write_text("from nmrl.runs import points\nfrom nmrl.experiments import sweep\n"
                   "def f():\n    points.place_points(1, 1)\n    sweep._place_points(1, 1)\n")
    refs = _nmrl_references(bad)
    assert ("nmrl.experiments.sweep", "_place_points", 5) in refs
    assert [r for r in refs if not _resolves(*r[:2])] == [("nmrl.experiments.sweep", "_place_points", 5)]


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
    from nmrl.adapters import brax_env

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
