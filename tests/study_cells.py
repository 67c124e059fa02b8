"""Every cell of every study, and the ``nmrl sweep`` command lines the kit runs for each.

:func:`every_cell` lists each study's cells by study: the ones it declares, the ones its rules make
from its published rows (``results/exploration2/runs``; the finer-delta studies' final cells from
their published ``grid.csv``), the amendment's rule-made cells, and the lab scripts' studies (the
NMp diagnosis, the gait stages at every stage's budget). :func:`commands` runs the kit's own
:func:`nmrl.experiments.kit.run_cell` on a cell with the sweep process replaced by a recorder, fresh
and as a resume, and returns what it would have run (the interpreter and directories as
placeholders, the points file as its content). tests/data/cell_commands.json holds these commands
as the argv cells of commit 172e6ba produced them (recorded by :func:`record` at commit 1baeb2a,
before the cells became typed data; tests/test_kit_cells.py compares). :func:`spec_of` is the sweep
spec that command makes, as ``nmrl sweep`` reads it.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
RECORD = ROOT / "tests" / "data" / "cell_commands.json"


def _script(name: str):
    path = ROOT / "scripts" / "lab" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"lab_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def every_cell() -> dict[str, tuple]:
    """Study name -> (the study as the kit runs it, its cells by name)."""
    from nmrl.experiments import exploration2, exploration2_amendment as amendment, kit, study, thesis_ac
    from nmrl.experiments.timescale import TimescaleSpec
    from nmrl.experiments.timescale_cells import points_cell
    from nmrl.experiments.timescale_tables import FINAL, chosen_betas
    from nmrl.runs import store

    out: dict[str, tuple] = {}
    out["exploration2"] = (exploration2.STUDY, kit.all_cells(exploration2.STUDY, RESULTS / "exploration2" / "runs"))
    out["exploration2_amendment"] = (amendment.STUDY, [*amendment.CELLS, amendment.family_cell("nmp", 0.0025),
                                                       amendment.wc_cell()])
    out["thesis_ac"] = (thesis_ac.STUDY, list(thesis_ac.STUDY.cells))
    for name in ("timescale", "timescale_cap", "timescale_cap300", None):
        d = RESULTS / (name or "timescale")
        spec = TimescaleSpec.from_json(json.loads((d / "study.json").read_text())) if name else TimescaleSpec()
        grid = store.read_csv(d / "grid.csv")
        cells = list(study.kit_study(spec, d).cells)
        if name:
            cells += [points_cell(FINAL, dt, *spec.final_points(dt, chosen_betas(grid, dt))) for dt in spec.dts]
        for progress in (True, False):
            s = study.kit_study(spec, d, progress=progress)
            out[f"{name or 'timescale_default'}{'' if progress else '_quiet'}"] = (s, cells)
    diag = _script("nmp_diagnosis")
    out["nmp_diagnosis"] = (kit.Study(name="nmp_diagnosis", cells=diag.cells(), endpoint=None), list(diag.cells()))
    stages = _script("gait_stages")
    out["gait_stages"] = (kit.Study(name="gait_stages", cells=(), endpoint=None),
                          [stages.cell(arm, it) for arm, its in stages.STAGES.items() for it in its])
    return {k: (s, {c.name if k != "gait_stages" else f"{c.name}@{i}": c for i, c in enumerate(cells)})
            for k, (s, cells) in out.items()}


def _capture(study, cell, d: pathlib.Path) -> dict:
    from nmrl.experiments import kit

    got: dict = {}

    def record(argv):
        argv = [a for a in argv]
        assert argv[:3] == [sys.executable, "-m", "nmrl.cli"], argv
        argv = argv[3:]
        if "--points" in argv:
            i = argv.index("--points")
            got["points"] = json.loads(pathlib.Path(argv[i + 1]).read_text())
            argv[i + 1] = "POINTS"
        got["argv"] = ["OUT" if a == str(d) else a for a in argv]
        return 0

    real = kit._sweep
    kit._sweep = record
    try:
        kit.run_cell(study, cell, d.parent)
    finally:
        kit._sweep = real
    return got


def commands(study, cell) -> dict:
    """What :func:`kit.run_cell` runs for ``cell`` of ``study``: ``fresh`` (a new directory) and
    ``resume`` (a directory holding the cell's sweep.json, not at its budget)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        fresh = dataclasses.replace(cell, name="c")
        res = {"fresh": _capture(study, fresh, root / "c")}
        (root / "c").mkdir()
        (root / "c" / "sweep.json").write_text(json.dumps({"points": list(cell.points)}))
        res["resume"] = _capture(study, fresh, root / "c")
    return res


def parsed(argv: list[str], learner: str) -> dict:
    """What ``nmrl sweep`` reads from ``argv`` (``["sweep", ...]``) with the learner ``learner`` (a
    resume's is the saved sweep's): every option's value as the command's parser gives it, and the
    options given (a listed-points sweep refuses some by their presence); ``--vary``'s values by its field's type, as
    the command reads them."""
    from nmrl.cli import arguments, config_options

    from nmrl import options

    lr = config_options.get_learner(learner)
    args = vars(arguments.build_parser(lr).parse_args(argv))
    if args.get("vary"):  # its values are read by the varied field's type (nmrl.cli.commands.varied_spec)
        name, *raw = args["vary"]
        args["vary"] = [name, *map(options.kind(lr.config, name), raw)]
    given = sorted({a.split("=", 1)[0] for a in argv if a.startswith("--")})
    return {"given": given, **{k: v for k, v in args.items() if k != "func"}}


def learner_of(argv: list[str]) -> str:
    return argv[argv.index("--learner") + 1] if "--learner" in argv else "ac"


def record() -> dict:
    """Every study's cells' commands (module docstring), by study and cell name."""
    return {k: {n: commands(s, c) for n, c in cells.items()} for k, (s, cells) in every_cell().items()}



def spec_of(study, cell):
    """The sweep spec ``nmrl sweep`` makes of the cell's fresh command line (nmrl/cli/commands.py's
    reading of it), its base config resolved as the sweep saves it in sweep.json."""
    from nmrl.cli import arguments, commands as cmds, config_options
    from nmrl.experiments import sweep

    with tempfile.TemporaryDirectory() as tmp:
        got = commands(study, cell)["fresh"]
        argv = list(got["argv"])
        if "points" in got:
            f = pathlib.Path(tmp) / "points.json"
            f.write_text(json.dumps(got["points"]))
            argv[argv.index("POINTS")] = str(f)
        learner = config_options.get_learner(learner_of(argv))
        args = arguments.build_parser(learner).parse_args(argv)
        args.argv = argv
        base = config_options.config_from_args(args, skip=cmds.sweep_skip(learner))
        if args.points is not None:
            spec = cmds.listed_spec(args, learner, base)
        elif args.vary is not None:
            spec = cmds.varied_spec(args, learner, base)
        else:
            spec = sweep.SweepSpec(ls=(None,), seeds=args.seeds, base=base, field=None, seed0=args.seed0)
    return dataclasses.replace(spec, base=spec.base.resolved())
