"""Benchmarks: `make bench` runs every bench/bench_*.py module in one process, one after the
other, so the figures are taken side by side on the same machine in the same run.

A module defines `run(out: Path, quick: bool) -> list[dict]`: rows of one table, each with
at least `name` and the measured figures (medians over repeats). Rows are written to
out/<module>.csv and out/results.json, and printed.
"""


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB. VmHWM, not ru_maxrss: Linux carries ru_maxrss
    over fork and exec, so a child of a big parent would report the parent's peak."""
    with open("/proc/self/status") as status:
        hwm = next(line for line in status if line.startswith("VmHWM:"))
    return int(hwm.split()[1]) / 1024
