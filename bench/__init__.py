"""Benchmarks: `make bench` (or `python -m bench [NAME ...]`). Not tests: numbers, not verdicts."""
