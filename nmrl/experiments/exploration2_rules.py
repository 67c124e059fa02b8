"""The second exploration study's rules (docs/exploration-study-2.md): from the rows so far, the
cells that follow.

The screen's rule (:func:`choose`: the value with the highest mean deterministic endpoint, never
one with a diverged run; a winner at an edge of the screened values extends the screen, at most
twice), then the grid of the primary settings, the secondary parts and the checks
(:func:`later_cells`); a rule reads only finished cells' rows (:func:`ended`).
"""

from __future__ import annotations

import dataclasses

from nmrl.experiments import kit
from nmrl.experiments.exploration2_cells import (ARMS, ASYMPTOTE_ITERATIONS, CORRELATED, GRID_SEEDS, MAX_EXTENSIONS,
                                                 PRIMARY, SCREEN_ITERATIONS, SCREEN_SEED0, SCREEN_SEEDS,
                                                 SECONDARY_SCREEN, SECONDARY_SEEDS, SIGMA_FACTOR, SIGMA_MAX,
                                                 SIGMA_SCREEN, SNR_POLICY_ITERATIONS, SNR_SEEDS, TIME_CONSTANTS,
                                                 arm_and_dt, asymptote_name, cell as cell_of, grid_cell,
                                                 grid_name,
                                                 scaled_white_sigma, snr_name)


def _finished(rows: list[dict], prefix: str) -> list[dict] | None:
    """The rows of the cells named ``prefix`` or ``prefix+...`` when every point is at its budget and
    scored; None while any is not."""
    mine = [r for r in rows if r["cell"] == prefix or r["cell"].startswith(prefix + "+")]
    if not mine or not all(ended(r) for r in mine):
        return None
    return mine


def diverged(r: dict) -> bool:
    """Whether a run's row says it diverged (``True`` as built by the kit or as read back from its CSV)."""
    return str(r["diverged"]) == "True"


def ended(r: dict) -> bool:
    """Whether a run's row is final: at its budget, or diverged (frozen at its last good policy),
    and scored."""
    return kit.ended(r) and r["det_reward_per_s"] != ""


def choose(rows: list[dict]) -> tuple[float, bool, list[float]] | None:
    """``(best value, at an edge, the values screened)`` of finished screen rows: the value whose
    seeds' mean deterministic reward per second is highest; a value with a diverged run is never
    chosen (None if every value has one)."""
    means = screen_means(rows)
    ok = {v: m for v, m in means.items() if m is not None}
    if not ok:
        return None
    best = max(ok, key=ok.get)
    values = sorted(means)
    return best, best in (values[0], values[-1]), values


def screen_means(rows: list[dict]) -> dict[float, float | None]:
    """Each screened value's mean deterministic reward per second over its seeds (None: a run diverged)."""
    by: dict[float, list[dict]] = {}
    for r in rows:
        by.setdefault(float(r["value"]), []).append(r)
    return {v: None if any(diverged(r) for r in rs)
            else sum(float(r["det_reward_per_s"]) for r in rs) / len(rs) for v, rs in by.items()}


def _extension(cell: kit.Cell, rows: list[dict], factor: float) -> kit.Cell | None:
    """The next value beyond the edge the winner sits at (``cell`` with that one value), if allowed.

    A period is at least one control step (l = round(period_s / dt) >= 1): an extension below that
    is the one-step period itself, and a winner at one step has nothing beyond it (it is used, at
    the edge of what exists)."""
    got = choose(rows)
    if got is None:
        return None
    best, edge, values = got
    n_ext = len({r["cell"] for r in rows if r["cell"].startswith(cell.name + "+")})
    if not edge or n_ext >= MAX_EXTENSIONS:
        return None
    nxt = best * factor if best == values[-1] else best / factor
    field = cell.vary[0]
    if field == "period_s":
        _, dt = arm_and_dt(cell.name)
        if round(best / dt) <= 1:
            return None
        nxt = max(nxt, dt)
    nxt = float(f"{nxt:.6g}")
    return dataclasses.replace(cell, name=f"{cell.name}+{nxt:.6g}", vary=(field, (nxt,)))


def _screen_state(rows: list[dict], cell: kit.Cell) -> tuple[list[kit.Cell], dict]:
    """One sigma-screen cell's rule (docs/exploration-study-2.md): the cells it adds so far (a sigma
    winner at an edge adds the next sigma, x or / 2.5, at most twice; once sigma is chosen, the
    arm's time constant's other values at that sigma, with the same edge extension by the values'
    own factor: x or / 3, beta x or / 2) and what it has decided: ``{"sigma": choice}`` once sigma
    is chosen, with ``{<time constant field>: choice}`` once that is, each choice as :func:`choose`
    gives it (best, at an edge, the values screened) with the rows it was decided on."""
    arm, dt = arm_and_dt(cell.name)
    done = _finished(rows, cell.name)
    if done is None:
        return [], {}
    ext = _extension(cell, done, SIGMA_FACTOR)
    if ext is not None:
        return [ext], {}
    sigma = choose(done)
    if sigma is None:
        return [], {}
    decided = {"sigma": (sigma, done)}
    if arm not in TIME_CONSTANTS:
        return [], decided
    field, vals, factor = TIME_CONSTANTS[arm]
    settings = {k: v for k, v in ARMS[arm].items() if k != field}  # the field is varied instead
    tc = cell_of(f"screen/tc/dt{dt:g}/{arm}", dt, SCREEN_ITERATIONS, {**settings, "sigma": float(f"{sigma[0]:.6g}")},
                 vary=(field, (float(f"{vals[0]:g}"), float(f"{vals[2]:g}"))), seeds=SCREEN_SEEDS, seed0=SCREEN_SEED0)
    tc_rows = _finished(rows, tc.name)
    if tc_rows is None:
        return [tc], decided
    at_sigma = [dict(r, value=vals[1]) for r in done if float(r["value"]) == sigma[0]]
    ext = _extension(tc, tc_rows + at_sigma, factor)
    if ext is not None:
        return [tc, ext], decided
    best = choose(tc_rows + at_sigma)
    return [tc], decided if best is None else {**decided, field: (best, tc_rows + at_sigma)}


def _screen(rows: list[dict], cell: kit.Cell) -> tuple[list[kit.Cell], dict | None]:
    """:func:`_screen_state`'s cells and, once every setting of the arm is decided, the choice
    ``{"sigma": ..., <time constant field>: ...}`` (None until then)."""
    add, state = _screen_state(rows, cell)
    arm, _ = arm_and_dt(cell.name)
    complete = "sigma" in state and (arm not in TIME_CONSTANTS or TIME_CONSTANTS[arm][0] in state)
    return add, {k: v[0][0] for k, v in state.items()} if complete else None


CHOICE_COLUMNS = ("arm", "control_dt", "setting", "value", "bracketed", "mean", "lead", "screened", "means")


def choices(rows: list[dict]) -> list[dict]:
    """What the screen has decided so far, per screened arm, control step and setting (sigma, then
    the time constant): the chosen value, whether it is bracketed (inside the values screened) or at
    an edge after the extensions the rule allows, its mean deterministic reward per second, its lead
    over the next best value, and every value screened with its mean ("diverged" for a value with a
    diverged run); a setting still screening is left out."""
    out = []
    for cell in (*SIGMA_SCREEN, *SECONDARY_SCREEN):
        arm, dt = arm_and_dt(cell.name)
        for setting, ((best, edge, values), decided_on) in _screen_state(rows, cell)[1].items():
            means = screen_means(decided_on)
            others = [m for v, m in means.items() if v != best and m is not None]
            out.append({"arm": arm, "control_dt": dt, "setting": setting, "value": best, "bracketed": not edge,
                        "mean": means[best], "lead": means[best] - max(others) if others else "",
                        "screened": " ".join(f"{v:g}" for v in values),
                        "means": " ".join("diverged" if means[v] is None else f"{means[v]:.1f}" for v in values)})
    return out


def later_cells(rows: list[dict]) -> list[kit.Cell]:
    """The cells the rows so far call for, in run order (docs/exploration-study-2.md): the screen's
    extensions and time constants; once every primary setting is chosen, the primary grid (W and NMp
    at 20 ms, W, Ws, OU, CN, NMs and NMp at 2.5 ms, 8 seeds, 16 iterations), then the secondary
    parts: the 5 ms column (W and NMp with the 2.5 ms choices, Ws by eq. (1)), OU, CN and NMs at
    20 ms with their own screens, 4 seeds each, and W's sigma sensitivity at 2.5 ms (one screen step
    either side of its choice). A Ws sigma above nmrl's range (10) is not run (reported)."""
    out: list[kit.Cell] = []
    chosen: dict[tuple[str, float], dict] = {}
    for cell in SIGMA_SCREEN:
        add, ch = _screen(rows, cell)
        out += add
        if ch is not None:
            chosen[arm_and_dt(cell.name)] = ch
    if any(key not in chosen for key in PRIMARY):
        return out
    s20 = chosen[("white", 0.02)]["sigma"]
    for arm, dt in PRIMARY:
        out.append(grid_cell(arm, dt, chosen[(arm, dt)], GRID_SEEDS))
        if arm == "white" and dt != 0.02 and scaled_white_sigma(s20, dt) <= SIGMA_MAX:  # at 20 ms Ws is W
            out.append(grid_cell("ws", dt, {"sigma": scaled_white_sigma(s20, dt)}, GRID_SEEDS))
    for arm in ("white", "ws", "nmp"):  # the 5 ms column takes the 2.5 ms choices
        ch = {"sigma": scaled_white_sigma(s20, 0.005)} if arm == "ws" else chosen[(arm, 0.0025)]
        if ch["sigma"] <= SIGMA_MAX:
            out.append(grid_cell(arm, 0.005, ch, SECONDARY_SEEDS))
    for cell in SECONDARY_SCREEN:
        add, ch = _screen(rows, cell)
        out += [cell, *add]
        if ch is not None:
            out.append(grid_cell(arm_and_dt(cell.name)[0], 0.02, ch, SECONDARY_SEEDS))
    sw = chosen[("white", 0.0025)]["sigma"]
    for s in (sw / SIGMA_FACTOR, sw * SIGMA_FACTOR):
        if s <= SIGMA_MAX:
            out.append(grid_cell("white", 0.0025, {"sigma": s}, SECONDARY_SEEDS,
                                 name=f"sensitivity/dt0.0025/white_sigma{s:.6g}"))
    best = best_correlated(rows)
    if best is not None:
        for arm in ("white", best):
            out.append(grid_cell(arm, 0.005, chosen[(arm, 0.0025)], SECONDARY_SEEDS,
                                 name=asymptote_name(arm), iterations=ASYMPTOTE_ITERATIONS))
    for it in SNR_POLICY_ITERATIONS:  # white's 20 ms policies for the SNR at matched policies
        out.append(grid_cell("white", 0.02, chosen[("white", 0.02)], SNR_SEEDS, name=snr_name(it), iterations=it))
    return out


def complete_cells(rows: list[dict], key: str = "det_reward_per_s") -> dict[str, list[float]]:
    """The endpoint ``key`` (default the deterministic reward per second; NaN where a row has none)
    of every cell whose runs all ended (at the budget, or diverged and scored by their last good
    policy) and were scored; a cell with a run still going is left out (its contrasts stay pending)."""
    by: dict[str, list[dict]] = {}
    for r in rows:
        if not r["cell"].startswith("screen/"):
            by.setdefault(r["cell"], []).append(r)
    return {c: [float(r[key]) if r.get(key, "") != "" else float("nan") for r in rs] for c, rs in by.items()
            if all(ended(r) for r in rs)}


def best_correlated(rows: list[dict]) -> str | None:
    """The correlated arm (OU, CN, NMs, NMp) whose 2.5 ms grid cell has the highest mean
    deterministic reward per second, once all four cells are complete (None before): the arm the
    asymptote runs against white."""
    cells = complete_cells(rows)
    means = {arm: sum(cells[grid_name(arm, 0.0025)]) / len(cells[grid_name(arm, 0.0025)]) for arm in CORRELATED
             if grid_name(arm, 0.0025) in cells}
    return max(means, key=means.get) if len(means) == len(CORRELATED) else None
