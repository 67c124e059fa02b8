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


#: ``pytest -m record``: the checks that recompute published results (results/) from committed data
#: and hold the published pages' numbers to them: these files whole, and these tests; selected by
#: default (CI runs them), ``-m 'not slow and not record'`` leaves them out
RECORD_FILES = {"test_exploration2_record.py", "test_exploration2_audit.py", "test_exploration2_secondary.py",
                "test_exploration2_asymptote.py", "test_exploration2_snr.py", "test_exploration2_noise.py"}
RECORD_TESTS = {"test_exploration_record.py::test_the_publisher_regenerates_the_committed_record_byte_for_byte",
                "test_exploration_record.py::test_the_answers_in_words_carry_welch_intervals_of_the_committed_rows",
                "test_thesis_ac.py::test_the_pages_fig3_numbers_are_the_committed_runs",
                "test_thesis_ac.py::test_the_pages_detectable_differences_are_the_noncentral_t",
                "test_thesis_ac.py::test_the_20_ms_cells_progress_numbers_are_the_published_rows",
                "test_exploration2_amendment.py::test_each_family_cell_is_its_grid_cell_at_twice_the_budget",
                "test_publish_timescale.py::test_a_study_directory_publishes_to_its_record_byte_for_byte",
                "test_publish_timescale.py::test_the_tables_carry_each_arms_mean_and_t_interval",
                "test_standard_tasks.py::test_the_publisher_regenerates_the_same_bytes_from_the_published_data",
                "test_standard_tasks.py::test_the_published_folder_regenerates_byte_for_byte",
                "test_publish.py::test_fast_preset_baseline_is_the_published_fig3_fast_sweep",
                "test_kit_cells.py::test_every_published_cell_is_the_sweep_its_sweep_json_holds"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        name = item.nodeid.rsplit("/", 1)[-1]
        if name.split("::")[0] in SMOKE_FILES or name.split("[")[0] in SMOKE_TESTS:
            item.add_marker(pytest.mark.smoke)
        if name.split("::")[0] in RECORD_FILES or name.split("[")[0] in RECORD_TESTS:
            item.add_marker(pytest.mark.record)
