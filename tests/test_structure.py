"""The package's architecture, read from the source with ``ast`` (nothing of nmrl is imported).

* no import cycle between the modules of ``nmrl`` (counting every import, also those inside
  functions: a lazy import is still a dependency);
* the layers point down only: ``nmrl.paper`` (the paper's ideas, pure JAX) < ``nmrl.explore``
  (exploration processes with exact likelihoods, pure JAX) < ``nmrl.learners`` (the learner contract
  and its implementations) and ``nmrl.adapters`` (bridges to other ecosystems) < ``nmrl.runs``
  (devices, run store, checkpoints, the driver) < ``nmrl.analysis`` (statistics, figures,
  evaluation) < ``nmrl.experiments`` (sweep, study, gradient variance) < ``nmrl.cli``;
* the package imports nothing from the checkout around it (``benchmarks``, ``scripts``, ``tests``),
  and neither scripts/, examples/ nor benchmarks/ edit ``sys.path`` (``pip install -e .`` is the way in);
* ``Trainer`` means one thing, the learner contract's Protocol (nmrl/learners/contract.py): no other
  class has that name, and every other module that names it takes that one;
* matplotlib's backend is set in one place, nmrl/analysis/plots.py, which the scripts, the
  benchmarks and the gait pictures draw with (the exploration study's figures aside: their module
  sets its own);
* benchmarks/ holds the code that measures, its measurements live in results/benchmarks/;
* no script commits to git: what enters the history is the caller's, never a launcher's or a
  publisher's.
"""

from __future__ import annotations

import ast
import pathlib
import re

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
PKG = REPO / "nmrl"
#: layer of each top-level part of nmrl; an import may only go to a layer <= its own
LAYERS = {"pytrees": 0, "options": 0, "physics": 0, "paper": 0, "tasks": 0, "explore": 1, "learners": 2, "adapters": 2, "runs": 3, "analysis": 4, "experiments": 5,
          "cli": 6, "__main__": 6}


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, pathlib.Path]:
    return {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _imported(path: pathlib.Path, name: str, modules: dict) -> tuple[set[str], set[str]]:
    """(modules of nmrl that ``name`` imports, other top-level packages it imports)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    here = name.split(".") if is_pkg else name.split(".")[:-1]
    targets: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            targets.append(mod)
            targets += [f"{mod}.{a.name}" for a in node.names]  # ``from pkg import module``
    inside, outside = set(), set()
    for t in targets:
        if t == "nmrl" or t.startswith("nmrl."):
            # the module itself if it is one, else the longest prefix that is (a name in a module)
            parts = t.split(".")
            while parts and ".".join(parts) not in modules:
                parts.pop()
            if parts and ".".join(parts) != name:
                inside.add(".".join(parts))
        else:
            outside.add(t.split(".")[0])
    return inside, outside


def _graph() -> dict[str, set[str]]:
    """Each module's imports inside nmrl. ``from nmrl import learners`` names the subpackage, not the
    root package's own content, so edges into ``nmrl`` itself are left out; the root's content is
    its lazy front door (``nmrl.train`` etc., nmrl/runs/api.py), which no module inside uses
    (:func:`test_no_module_uses_the_front_door`)."""
    mods = _modules()
    return {n: _imported(p, n, mods)[0] - ({"nmrl"} if n != "nmrl" else set()) for n, p in mods.items()}


def test_no_module_uses_the_front_door():
    import nmrl

    hits = [n for n, p in _modules().items() if n not in ("nmrl", "nmrl.runs.api") and any(
        f"from nmrl import {name}" in p.read_text() or f"nmrl.{name}(" in p.read_text() for name in nmrl.__all__)]
    assert not hits, f"modules inside nmrl that use nmrl's front door: {hits}"


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules (first == last), or None."""
    color: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        color[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if color.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in color:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        color[n] = 2
        return None

    for n in sorted(graph):
        if n not in color:
            found = visit(n)
            if found:
                return found
    return None


def test_cycle_finder_finds_a_cycle():
    """The checker itself: a planted cycle a -> b -> c -> a is found, a DAG passes."""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_inside_nmrl():
    graph = _graph()
    assert len(graph) > 15, sorted(graph)  # the walk found the package
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.get(parts[1]) if len(parts) > 1 else None


def test_every_module_has_a_layer():
    loose = [n for n in _modules() if n != "nmrl" and _layer(n) is None]
    assert not loose, f"modules outside the layers {sorted(LAYERS)}: {loose}"


def test_imports_point_down_only():
    bad = []
    for n, deps in _graph().items():
        for d in deps:
            if d == "nmrl" or n == "nmrl":  # the root package: its lazy front door sits above every layer
                continue
            if _layer(d) > _layer(n):
                bad.append(f"{n} (layer {_layer(n)}) imports {d} (layer {_layer(d)})")
    assert not bad, "\n".join(sorted(bad))


@pytest.mark.parametrize("module, forbidden", [
    # the paper's ideas are pure JAX: no files, figures, checkpoints, progress bars or processes
    ("nmrl.paper", {"orbax", "matplotlib", "imageio", "rich", "csv", "json", "subprocess", "signal"}),
    ("nmrl.explore", {"orbax", "matplotlib", "imageio", "rich", "csv", "json", "subprocess", "signal", "os", "pathlib"}),
    # nmrl.runs.devices decides the device count before JAX starts
    ("nmrl.runs.devices", {"jax", "jaxlib"}),
    # the watcher of a distributed process stays small: it never starts JAX
    ("nmrl.runs.launch", {"jax", "jaxlib", "numpy"}),
    # statistics do not pull in matplotlib
    ("nmrl.analysis.stats", {"matplotlib"}),
])
def test_forbidden_imports(module, forbidden):
    mods = _modules()
    hit = []
    for n, p in mods.items():
        if n == module or n.startswith(module + "."):
            _, outside = _imported(p, n, mods)
            hit += [f"{n} imports {o}" for o in sorted(outside & forbidden)]
    assert not hit, hit


def test_brax_stays_optional():
    """Brax (an optional extra) is imported only by the adapter and the PPO baseline's Brax side
    (nmrl/experiments/baseline_brax.py), and there only inside a guard or a function: importing nmrl
    never needs it."""
    mods = _modules()
    users = sorted(n for n, p in mods.items() if "brax" in _imported(p, n, mods)[1])
    assert users == ["nmrl.adapters.brax_env", "nmrl.experiments.baseline_brax"], users
    for n in users:
        tree = ast.parse(mods[n].read_text())
        top = [node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
        roots = [(node.module or "").split(".")[0] if isinstance(node, ast.ImportFrom) else a.name.split(".")[0]
                 for node in top for a in node.names]
        assert "brax" not in roots, f"{n} imports brax unguarded"


def test_gradvar_does_not_pull_in_figures_or_the_sweep():
    graph = _graph()
    seen, todo = set(), ["nmrl.experiments.gradvar"]
    while todo:
        n = todo.pop()
        if n not in seen:
            seen.add(n)
            todo += graph.get(n, ())
    assert not seen & {"nmrl.analysis.plots", "nmrl.experiments.sweep"}, sorted(seen)


def test_package_imports_nothing_from_the_checkout():
    mods = _modules()
    hit = []
    for n, p in mods.items():
        _, outside = _imported(p, n, mods)
        hit += [f"{n} imports {o}" for o in sorted(outside & {"benchmarks", "scripts", "tests", "tiny_env"})]
        if "sys.path" in p.read_text():
            hit.append(f"{n} touches sys.path")
    assert not hit, hit


def test_scripts_and_benchmarks_do_not_edit_sys_path():
    hit = []
    for p in [*sorted((REPO / "scripts").rglob("*.py")), *sorted((REPO / "examples").rglob("*.py")),
              *sorted((REPO / "benchmarks").glob("*.py"))]:
        for node in ast.walk(ast.parse(p.read_text())):
            if (isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name)
                    and node.value.id == "sys"):
                hit.append(f"{p.relative_to(REPO)}:{node.lineno}")
    assert not hit, f"sys.path edited in {hit}; the package is installed (pip install -e .)"


def test_no_script_commits():
    commit = re.compile(r"""git\s+(-\S+\s+)*commit\b|["']git["'],\s*["']commit["']""")
    hit = []
    for p in sorted([*(REPO / "scripts").rglob("*.sh"), *(REPO / "scripts").rglob("*.py"),
                     *(REPO / "benchmarks").glob("*.py")]):
        for n, line in enumerate(p.read_text().splitlines(), 1):
            code = line.split("#", 1)[0] if p.suffix == ".sh" else line
            if commit.search(code):
                hit.append(f"{p.relative_to(REPO)}:{n}")
    assert not hit, f"git commit run by {hit}"


def test_benchmarks_hold_code_only():
    import subprocess

    files = subprocess.run(["git", "ls-files", "benchmarks"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split()
    assert files, "git ls-files found nothing under benchmarks/"
    outputs = [f for f in files if not f.endswith(".py")]
    assert not outputs, f"measurements beside the benchmarks' code (their place: results/benchmarks/): {outputs}"


def test_matplotlib_backend_is_set_in_one_place():
    own = {"nmrl/analysis/plots.py"}
    hit = []
    for top in ("nmrl", "scripts", "benchmarks", "examples"):
        for p in sorted((REPO / top).rglob("*.py")):
            rel = str(p.relative_to(REPO))
            for node in ast.walk(ast.parse(p.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "use"
                        and isinstance(node.func.value, ast.Name) and node.func.value.id == "matplotlib"
                        and rel not in own):
                    hit.append(f"{rel}:{node.lineno}")
    assert not hit, f"matplotlib.use outside nmrl/analysis/plots.py (draw with its plt and save): {hit}"


def test_trainer_names_one_thing():
    classes, others = [], []
    for p in sorted(PKG.rglob("*.py")):
        rel = str(p.relative_to(REPO))
        for node in ast.parse(p.read_text()).body:
            if isinstance(node, ast.ClassDef) and node.name == "Trainer":
                classes.append(rel)
            elif (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "Trainer"
                                                       for t in node.targets)
                  and ast.unparse(node.value) != "learners.Trainer"):
                others.append(f"{rel}: Trainer = {ast.unparse(node.value)}")
    assert classes == ["nmrl/learners/contract.py"], classes
    assert not others, others
