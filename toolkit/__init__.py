"""Toolkit for 2D laser robot logs: datasets in Parquet, Gaussian scan alignment, maps and
learned place features, after Aznar, Pujol et al., PLoS ONE 2014.

    import toolkit
    ds = toolkit.load("runs/intel")      # Dataset: .t, .ranges (S x B float32), .angles, ...
"""

from __future__ import annotations

__version__ = "0.1.0"

from toolkit import align
from toolkit.dataset import Dataset, ImportReport, LaserGeometry, load, save
from toolkit.errors import ToolkitError

# The function, not the module: `toolkit.trajectory(ds, method="gaussian")`. Imported here,
# eagerly, so that a later `import toolkit.trajectory` finds the module loaded and leaves
# this name alone.
from toolkit.trajectory import trajectory

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
