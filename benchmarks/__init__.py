"""Benchmarks of nmrl: ``python -m benchmarks [--quick]`` (see benchmarks/__main__.py)."""
