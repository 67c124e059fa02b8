"""``nmrl sweep --points FILE``: the points of a sweep listed one by one, read from a JSON file.

The file is a list of objects, one per point: ``{"name": "stationary_bt1e-05", "beta_theta": 1e-05,
"l": 1, "seed": 0}``, each a name (the point's directory under ``points/``) and the config fields it
sets on the base config the command's options give. The points may differ only in the learner's
traced hyperparameters and the seed, so one compiled program runs them all
(nmrl.experiments.sweep.SweepSpec checks it, naming the first point that differs otherwise); the
budget (``--steps``/``--trials``) is the sweep's. Every value is read as its field's type (an
integer field takes integers, a float field any number, a boolean field true or false); a file
that is not such a list is refused with one line naming what is wrong, before anything is written.
"""

from __future__ import annotations

import json
import math

from nmrl import options
from nmrl.cli.config_options import field_type
from nmrl.runs.signals import setting_up

#: the largest points file read (a list of a few thousand points is far below it)
MAX_BYTES = 16 * 2**20


def _value(point: str, name: str, v, t: type):
    """``v`` as the field's type ``t``; ValueError naming the point, the field and the value."""
    bad = ValueError(f"--points: point {point!r}: {name}={v!r} is invalid: {name} takes {t.__name__} values")
    if v is None or isinstance(v, bool) != (t is bool):
        raise bad
    if t is bool or t is str:
        if not isinstance(v, t):
            raise bad
        return v
    if t is int:
        if not isinstance(v, int):
            raise bad
        return v
    if t is float:
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            raise bad
        return float(v)
    raise bad


def read_points(path: str, config: type) -> tuple[dict, ...]:
    """The points of ``path`` for a learner whose config class is ``config``, each value of its
    field's type; ValueError (one line) if the file is missing, not JSON or not a list of points."""
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise ValueError(f"--points={path!r} is invalid: {(e.strerror or str(e)).lower()}") from None
    if len(raw) > MAX_BYTES:
        raise ValueError(f"--points={path!r} is invalid: larger than {MAX_BYTES // 2**20} MiB")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"--points={path!r} is invalid: not JSON ({str(e).splitlines()[0]})") from None
    if not isinstance(data, list) or not data or not all(isinstance(p, dict) for p in data):
        raise ValueError(f"--points={path!r} is invalid: give a non-empty JSON list of objects, one per point, "
                         f"e.g. [{{\"name\": \"a\", \"beta_theta\": 1e-05}}]")
    fields = options.leaves(config)
    types = {n: field_type(config, n) for n in fields}  # once: typing's hints are slow per point
    out = []
    for i, p in enumerate(setting_up(data, len(data), step="reading the points file")):
        name = p.get("name")
        label = name if isinstance(name, str) else f"#{i}"
        q = {"name": name}
        for k, v in p.items():
            if k == "name":
                continue
            if k not in fields:
                raise ValueError(f"--points: point {label!r} sets {k!r}, which is not a field of the learner's "
                                 f"config")
            q[k] = _value(label, k, v, types[k])
        out.append(q)
    return tuple(out)
