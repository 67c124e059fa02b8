"""Benchmarks of nmrl: ``python -m benchmarks [--quick]`` (see benchmarks/__main__.py)."""

import os


def subprocess_env() -> dict:
    """The environment for a benchmark's ``nmrl`` subprocess: CPU JAX, the persistent compile cache,
    no inherited XLA_FLAGS (the command sets its own device count)."""
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    env["JAX_PLATFORMS"] = "cpu"
    env.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))
    return env
