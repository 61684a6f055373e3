"""Toolkit for 2D laser robot logs: datasets in Parquet, Gaussian scan alignment, maps and
learned place features, after Aznar, Pujol et al., PLoS ONE 2014.

    import toolkit
    ds = toolkit.load("runs/intel")      # Dataset: .t, .ranges (S x B float32), .angles, ...
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from toolkit import align
    from toolkit.dataset import Dataset, ImportReport, LaserGeometry, load, save
    from toolkit.poses import trajectory

_DATASET = ("Dataset", "ImportReport", "LaserGeometry", "load", "save")


def __getattr__(name: str) -> object:
    """`toolkit.align` and `toolkit.trajectory(ds, method)` load the numba matcher on first
    use, so that commands which do not align (info, import, ...) start without it; the
    dataset names load pandas and pyarrow on first use, so that the `toolkit` command can
    set up its signal handling before any heavy import (`toolkit.app.entry`)."""
    if name in _DATASET:
        return getattr(importlib.import_module("toolkit.dataset"), name)
    if name == "align":
        return importlib.import_module("toolkit.align")
    if name == "trajectory":
        return importlib.import_module("toolkit.poses").trajectory
    raise AttributeError(f"module 'toolkit' has no attribute {name!r}")


__all__ = [
    "Dataset",
    "ImportReport",
    "LaserGeometry",
    "ToolkitError",
    "align",
    "load",
    "save",
    "trajectory",
]
