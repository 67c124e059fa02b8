"""Shared test set-up: CPU JAX and a persistent XLA compilation cache.

Many tests build the same jitted programs (the Half-Cheetah step, the training chunk) in separate
trainers; the on-disk cache turns their repeated compiles into look-ups. Subprocesses (CLI tests)
inherit the cache through the environment variables.
"""

import os
import pathlib
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_CACHE = pathlib.Path(tempfile.gettempdir()) / "nmrl-test-xla-cache"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402

jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


import pathlib as _pathlib
import re as _re  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture
def saved_figures(monkeypatch):
    """Every matplotlib Figure saved during the test, as (path, figure): the figure's content (its
    Axes, lines, collections, labels) can then be checked, not only the file it became."""
    import matplotlib.figure

    saved: list = []
    savefig = matplotlib.figure.Figure.savefig

    def recording_savefig(self, fname, *args, **kwargs):
        path = _pathlib.Path(fname)  # an atomic write saves to ".<stem>.<pid>.tmp<suffix>" first
        m = _re.fullmatch(r"\.(.+)\.\d+\.tmp(\.[^.]*)?", path.name)
        saved.append((path.with_name(m[1] + (m[2] or "")) if m else path, self))
        return savefig(self, fname, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", recording_savefig)
    return saved


#: ``pytest -m smoke``: a check of an install in a minute or two on 2 cores (README): these files
#: whole, and these tests (one end-to-end sweep on MuJoCo C among them)
SMOKE_FILES = {"test_networks.py", "test_structure.py", "test_options.py", "test_noise.py", "test_prereg_stats.py",
               "test_plots.py"}
SMOKE_TESTS = {"test_sweep_points.py::test_points_that_set_the_environments_fields_run_in_that_environment",
               "test_cli.py::test_bare_nmrl_shows_the_commands_and_version_names_the_package",
               "test_cli.py::test_a_ppo_budget_below_one_iteration_is_refused_naming_the_iteration"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        name = item.nodeid.rsplit("/", 1)[-1]
        if name.split("::")[0] in SMOKE_FILES or name.split("[")[0] in SMOKE_TESTS:
            item.add_marker(pytest.mark.smoke)
