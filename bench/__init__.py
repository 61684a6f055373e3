"""Benchmarks: `make bench` runs every bench/bench_*.py module in one process, one after the
other, so the figures are taken side by side on the same machine in the same run.

A module defines `run(out: Path, quick: bool) -> list[dict]`: rows of one table, each with
at least `name` and the measured figures (medians over repeats). Rows are written to
out/<module>.csv and out/results.json, and printed.
"""
