"""Does a random initial period phase change the first 10^4 trials of Fig. 3 at the paper's budget?

In a fresh run every environment starts its first nm-period at step 0, so for the first few hundred
control steps the periods of all N environments end at the same steps (t = l, 2l, ...) and the
summed updates of Table II arrive in bursts; the trial stops (probability 1/250 per step) then
randomise the phases: the share of environments never stopped after t steps is (1 - 1/250)^t
(1.8 % after 1000 steps, 0.03 % after 2000).

This script runs the *mixed-phase* variant: the same initial networks as the paper-scale sweep's
points (init key PRNGKey(seed)), first ``--warmup`` control steps with the step sizes set to 0 (the
policy does not change; trials stop and restart, which randomises the phases), then the counters
and the traces are reset and learning starts with the paper's step sizes from those mixed phases.
Its learning curves are compared, seed by seed, with the sweep's points, which start in phase
(``--sweep``, default runs/fig3_paper): the average reward per step during learning at 2,000, 5,000
and 10,000 trials (mean over the chunks whose trial count lies in (0.9 M, M]).

    .venv/bin/python scripts/lab/phase_check.py [--ls 10 30] [--seeds 3] [--trials 10000]

Writes runs/phase_check/points/l<l>_s<seed>/metrics.jsonl (one row per chunk, the sweeps' layout)
and results/phase_check/phase_check.json with a copy of those metrics.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

from nmrl import options

MILESTONES = (2_000, 5_000, 10_000)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ls", type=int, nargs="+", default=[10, 30])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--trials", type=int, default=10_000)
    ap.add_argument("--warmup", type=int, default=2000, help="control steps with zero step sizes")
    ap.add_argument("--num-envs", type=int, default=32)
    ap.add_argument("--chunk-steps", type=int, default=1000)
    ap.add_argument("--sweep", default="runs/fig3_paper")
    ap.add_argument("--out", default="runs/phase_check")
    ap.add_argument("--results", default="results/phase_check")
    ap.add_argument("--summarize", action="store_true",
                    help="only (re)compute the comparison from runs already in --out and --sweep")
    args = ap.parse_args(argv)
    for name in ("seeds", "trials", "warmup", "num_envs", "chunk_steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')}={getattr(args, name)} is invalid: must be >= 1")
    if args.warmup % args.chunk_steps:
        ap.error(f"--warmup={args.warmup} must be a multiple of --chunk-steps={args.chunk_steps}")

    from nmrl.runs import devices

    devices.configure(None)
    if args.summarize:
        names = [f"l{l}_s{s}" for l in args.ls for s in range(args.seeds)]
        return summarize(args, names, pathlib.Path(args.out))
    import jax
    import jax.numpy as jnp
    import numpy as np

    from nmrl.runs import loop, points, store
    from nmrl.experiments import sweep
    from nmrl.analysis import stats
    from nmrl.learners.ac_config import Hyper, TrainConfig
    from nmrl.learners.ac_train import make_train

    cfgs = [options.build(TrainConfig, l=l, seed=s, num_envs=args.num_envs, chunk_steps=args.chunk_steps,
                        trials=args.trials).resolved() for l in args.ls for s in range(args.seeds)]
    names = [f"l{c.l}_s{c.budget.seed}" for c in cfgs]
    P = len(cfgs)
    tr = make_train(cfgs[0])
    n_dev = min(len(jax.local_devices()), P)
    slots = points.slot_order(P, n_dev)
    hyp = [Hyper.from_config(c) for c in cfgs]
    zero = [h._replace(beta_theta=jnp.zeros_like(h.beta_theta), beta_v=jnp.zeros_like(h.beta_v)) for h in hyp]
    pick = lambda xs: [xs[i if i >= 0 else 0] for i in slots]  # noqa: E731
    keys = jnp.stack(pick([jax.random.PRNGKey(c.budget.seed) for c in cfgs]))
    ts = jax.jit(jax.vmap(tr.init))(keys, points.stack_trees(pick(zero)))
    ts = points.place_points(ts, n_dev)
    program = points.points_program(tr.chunk, n_dev)
    act = points.place_points(jnp.asarray([i >= 0 for i in slots]), n_dev)
    chunk = jax.jit(program, donate_argnums=0).lower(ts, act).compile()
    print(f"phase_check: {P} points on {n_dev} device(s); warm-up {args.warmup} steps at zero step sizes",
          file=sys.stderr, flush=True)
    for _ in range(args.warmup // args.chunk_steps):
        ts, _m = chunk(ts, act)
    # learning starts: the paper's step sizes, counters and traces at zero, phases as the warm-up left them
    zeros = lambda: jnp.zeros(ts.step.shape, ts.step.dtype)  # noqa: E731  (distinct buffers: donated)
    ts = ts.replace(hyper=points.place_points(points.stack_trees(pick(hyp)), n_dev), step=zeros(), trials=zeros(),
                    periods=zeros(), slots=ts.slots.replace(z=jax.tree.map(jnp.zeros_like, ts.slots.z),
                                                        y=jax.tree.map(jnp.zeros_like, ts.slots.y)))
    ts = points.place_points(ts, n_dev)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for n in names:
        _metrics(out, n).unlink(missing_ok=True)
        _metrics(out, n).parent.mkdir(parents=True, exist_ok=True)
    done = np.zeros(P, bool)
    t0 = time.time()
    while not done.all():
        act_now = points.place_points(jnp.asarray([i >= 0 and not done[i] for i in slots]), n_dev)
        t1 = time.time()
        ts, m = chunk(ts, act_now)
        m = jax.device_get(m)
        wall = time.time() - t1
        for j, i in enumerate(slots):
            if i < 0 or done[i]:
                continue
            row = loop.metrics_row(cfgs[i], store.to_python({k: v[j] for k, v in m.items()}), wall,
                                  points=int((~done).sum()))
            with open(_metrics(out, names[i]), "a") as f:
                f.write(json.dumps(row) + "\n")
            done[i] = row["trials"] >= args.trials or store.is_diverged(row)
        print(f"phase_check: {time.time() - t0:,.0f} s, trials "
              f"{min(int(t) for t in np.asarray(ts.trials)):,}", file=sys.stderr, flush=True)

    return summarize(args, names, out)


def _metrics(root: pathlib.Path, name: str) -> pathlib.Path:
    """A run's rows in a sweep's layout: ``root/points/<name>/metrics.jsonl``."""
    return root / "points" / name / "metrics.jsonl"


def _read(path: pathlib.Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else []


def summarize(args, names, out: pathlib.Path) -> int:
    import numpy as np

    from nmrl.runs import loop, points, store
    from nmrl.experiments import sweep
    from nmrl.analysis import stats

    res = {"what": __doc__.split("\n")[0], "args": vars(args), "milestones": list(MILESTONES), "by_l": {}}
    for l in args.ls:
        e = {}
        for M in MILESTONES:
            mixed = [stats.at_milestone(_read(_metrics(out, f"l{l}_s{s}")), M) for s in range(args.seeds)]
            inph = [stats.at_milestone(store.read_metrics(sweep.point_dir(pathlib.Path(args.sweep), l, s)), M) for s in range(args.seeds)]
            diff = [a - b for a, b in zip(mixed, inph) if a is not None and b is not None]
            # a paired comparison: the same initial networks (PRNGKey(seed)), different phases and noise
            mm = stats.mean_ci95(np.array([x for x in mixed if x is not None])) if None not in mixed else (None, None)
            mi = stats.mean_ci95(np.array([x for x in inph if x is not None])) if None not in inph else (None, None)
            md = stats.mean_ci95(np.array(diff)) if len(diff) == args.seeds else (None, None)
            e[str(M)] = {"mixed_phase": mixed, "in_phase": inph, "mixed_mean_ci": mm, "in_phase_mean_ci": mi,
                         "paired_diff_mean_ci": md}
        res["by_l"][str(l)] = e
    dest = pathlib.Path(args.results)
    dest.mkdir(parents=True, exist_ok=True)
    store.atomic_write_text(dest / "phase_check.json", json.dumps(res, indent=1) + "\n")
    for n in names:
        store.atomic_copy(_metrics(out, n), _metrics(dest, n))
    print(json.dumps(res["by_l"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
