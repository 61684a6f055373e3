"""Table 2 and Fig. 4-5: Gaussian alignment against ICP on random point clouds.

The protocol (cloud, shift, noise, trials, timing) is the benchmark's own
(`bench/bench_align.py`), run here with the paper's five sizes so that the report's times
are measured in the run that writes it.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

import numpy as np
import pandas as pd

from reports.base import NotAvailable, Section, new_figure, require, save_figure, save_table
from reports.context import ROOT, Context

KEY = "table2"
TITLE = "Table 2 and Fig. 4-5: random point clouds"
INTRO = (
    "Random 3D clouds of 100 to 10,000 points, shifted and with noise added; the Gaussian "
    "alignment knows the correspondence by index, ICP finds it by nearest neighbours. Mean "
    "translation error over the trials and median time per alignment, measured in this run."
)

SIZES = (100, 500, 1000, 5000, 10_000)  # the paper's
LABELS = {"gaussian": "Gaussian (text Eq. 6)", "gaussian-paper": "Gaussian (printed Eq. 6)"}


QUICK_TRIALS = 2


@contextmanager
def _protocol(bench: ModuleType, trials: int | None) -> Iterator[None]:
    """The benchmark's protocol at the paper's sizes (its own list is shorter), and with
    fewer trials in quick mode (its quick mode also drops sizes)."""
    saved = {name: getattr(bench, name) for name in ("SIZES", "TRIALS")}
    setattr(bench, "SIZES", SIZES)  # noqa: B010 - a module's constant, restored below
    if trials is not None:
        setattr(bench, "TRIALS", trials)  # noqa: B010
    try:
        yield
    finally:
        for name, value in saved.items():
            setattr(bench, name, value)


def protocol_module() -> ModuleType:
    """The benchmark module holding the protocol. `bench/` is not an installed package, so
    the `toolkit` command (whose sys.path lacks the repo) loads it from the source tree."""
    try:
        return require("bench.bench_align", "run", "SIZES", "TRIALS")
    except NotAvailable:
        path = ROOT / "bench" / "bench_align.py"
        if not path.is_file():
            raise NotAvailable(
                "the Table 2 protocol lives in bench/bench_align.py, which is not installed"
            ) from None
        spec = importlib.util.spec_from_file_location("bench_align_protocol", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        for name in ("run", "SIZES", "TRIALS"):
            if not hasattr(module, name):
                raise NotAvailable(f"{path} lacks {name}") from None
        return module


def cloud_rows(ctx: Context) -> pd.DataFrame:
    """Rows of the benchmark's protocol at the paper's sizes: one per method and size."""
    bench = protocol_module()
    ctx.step("random clouds")
    with _protocol(bench, QUICK_TRIALS if ctx.quick else None):
        rows: list[dict[str, Any]] = bench.run(ctx.work, False)
    return pd.DataFrame(rows)


def generate(ctx: Context, section: Section) -> None:
    frame = cloud_rows(ctx)
    table = pd.DataFrame(
        {
            "points": frame["points"].astype(int),
            "method": frame["name"].astype(str),
            "trials": frame["trials"].astype(int),
            "error (mm)": 1000.0 * frame["error_m"].astype(float),
            "time (ms)": 1000.0 * frame["seconds"].astype(float),
            "speed-up vs ICP": frame["speedup_vs_icp"].astype(float),
        }
    )
    if "error_std_m" in frame:
        table.insert(4, "error std (mm)", 1000.0 * frame["error_std_m"].astype(float))
    else:
        section.notes.append(
            "The benchmark protocol reports the mean error over the trials but not its "
            "standard deviation, so the table has no std column."
        )
    table = table.sort_values(["points", "method"], kind="stable").reset_index(drop=True)
    section.data["table2"] = table
    section.tables.append(
        save_table(
            table,
            ctx.out,
            "table2_clouds",
            "Table 2: random clouds, Gaussian alignment against ICP",
            "Translation error (mean over trials) and median time per alignment, by cloud size.",
            {"error (mm)": "{:.3f}", "error std (mm)": "{:.3f}", "time (ms)": "{:.3f}"},
        )
    )
    section.figures.append(_time_figure(ctx, table, ours_only=False))
    section.figures.append(_time_figure(ctx, table, ours_only=True))


def _time_figure(ctx: Context, table: pd.DataFrame, ours_only: bool) -> Any:
    fig = new_figure(6.0, 4.0)
    ax = fig.add_subplot()
    data: dict[str, dict[str, list[float]]] = {}
    for method, rows in table.groupby("method", sort=True):
        name = str(method)
        if ours_only and not name.startswith("gaussian"):
            continue
        rows = rows.sort_values("points")
        x = rows["points"].to_numpy(dtype=float)
        y = rows["time (ms)"].to_numpy(dtype=float)
        data[name] = {"points": x.tolist(), "time_ms": y.tolist()}
        ax.plot(x, y, marker="o", label=LABELS.get(name, name.upper()))
    ax.set_xscale("log")
    if not ours_only:
        ax.set_yscale("log")
    ax.set_xlabel("points")
    ax.set_ylabel("time per alignment (ms)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if ours_only:
        name, title = "fig5_time_gaussian", "Fig. 5: run time against size, Gaussian alignment"
        caption = "Median time per alignment of the Gaussian alignment alone (linear in N)."
        # a straight line through the origin is what O(N) predicts
        for values in data.values():
            x, y = np.array(values["points"]), np.array(values["time_ms"])
            values["slope_ms_per_point"] = [float(np.dot(x, y) / np.dot(x, x))]
    else:
        name, title = "fig4_time_both", "Fig. 4: run time against size, both methods"
        caption = "Median time per alignment, Gaussian alignment and ICP (log-log)."
    return save_figure(fig, ctx.out, name, title, caption, data)
