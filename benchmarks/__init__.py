"""Benchmarks: each ``bench_*.py`` module measures figures against a reference run in the same process."""
