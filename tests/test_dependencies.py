"""The install's two dependency statements agree: every requirement of pyproject.toml (the project's
and its extras') is pinned in requirements.lock, and the pinned version lies in pyproject's range,
so that the README's install (``pip install -c requirements.lock -e '.[dev]'``) resolves to the lock,
and the lock is what this environment runs (CI installs with it)."""

from __future__ import annotations

import pathlib
import tomllib
from importlib import metadata

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _lock() -> dict[str, str]:
    pins = {}
    for line in (ROOT / "requirements.lock").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, version = line.split("==")
            pins[canonicalize_name(name)] = version
    return pins


def _requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = [r for group in project.get("optional-dependencies", {}).values() for r in group]
    return [Requirement(r) for r in (*project["dependencies"], *extras)]


def test_every_requirement_is_locked_within_its_range():
    pins = _lock()
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not in requirements.lock"
        assert req.specifier.contains(pins[name], prereleases=True), \
            f"requirements.lock pins {req.name}=={pins[name]}, outside pyproject's {req.specifier}"


def test_the_environment_runs_the_lock():
    installed = {canonicalize_name(d.metadata["Name"]): d.version for d in metadata.distributions()}
    for req in _requirements():
        name = canonicalize_name(req.name)
        if name in installed:  # an optional extra that is not installed (brax) is not checked
            assert installed[name] == _lock()[name], f"{req.name} {installed[name]} installed, lock {_lock()[name]}"
