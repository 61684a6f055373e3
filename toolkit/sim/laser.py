"""Laser model: a SICK LMS-200 (180° at 1°, 181 beams) seeing a `World`.

What a reading is, in order:

1. the true range to the nearest opaque surface (walls, columns, tables), from the laser's
   mounting position (`mount_x` ahead of the robot's centre);
2. glass (windows): within `glass_normal_deg` of normal incidence the pane gives a weak return
   (with probability `glass_return_prob`, extra noise `glass_sigma`, else no return); at
   larger incidence the beam passes through and reads whatever is behind, or nothing;
3. Gaussian range noise `range_sigma`;
4. mixed pixels: where neighbouring beams hit different objects at ranges more than
   `mixed_jump` apart (a depth edge, not a wall seen at a grazing angle), the beam on the far side reads, with probability `mixed_prob`, a value between the
   foreground and the background range (the footprint straddles the edge);
5. quantization to the LMS-200 unit (`units` "cm": 1 cm, 80 m maximum; "mm": 1 mm, 8 m);
   readings at or beyond the maximum range, or below `range_min`, are NaN (no return).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from toolkit.dataset import LaserGeometry
from toolkit.errors import ToolkitError
from toolkit.sim.geometry import World, cast
from toolkit.typed import check_fields

UNITS = {"cm": (0.01, 80.0), "mm": (0.001, 8.0)}  # resolution, maximum range (m)


@dataclass
class LaserModel:
    """LMS-200 geometry and error model; every field is a documented simulator parameter."""

    units: Literal["cm", "mm"] = "cm"  # "cm" (80 m mode) or "mm" (8 m mode)
    beams: int = 181  # 180° at 1°
    fov_deg: float = 180.0
    range_min: float = 0.05  # m; closer readings are invalid
    range_sigma: float = 0.01  # m, Gaussian range noise (LMS-200: ±15 mm typical)
    glass_normal_deg: float = 15.0  # glass returns only within this angle of normal incidence
    glass_return_prob: float = 0.7  # chance of a weak glass return when near normal
    glass_sigma: float = 0.03  # m, extra noise of a weak glass return
    mixed_prob: float = 0.5  # chance that a beam at a depth edge is a mixed pixel
    mixed_jump: float = 0.3  # m, neighbour difference that makes a depth edge
    mount_x: float = 0.16  # m, laser ahead of the robot centre
    mount_z: float = 0.30  # m, laser height (for 3D maps)

    def __post_init__(self) -> None:
        check_fields(self, "the simulator")  # types and choices, as `toolkit simulate` parses
        if self.beams < 2:
            raise ToolkitError(f"beams={self.beams} for the simulator: a scan needs at least 2")

    @property
    def resolution(self) -> float:
        return UNITS[self.units][0]

    @property
    def range_max(self) -> float:
        return UNITS[self.units][1]

    def geometry(self) -> LaserGeometry:
        fov = np.deg2rad(self.fov_deg)
        return LaserGeometry(
            beams=self.beams,
            angle_min=float(-fov / 2),
            angle_increment=float(fov / (self.beams - 1)),
            range_max=self.range_max,
            range_min=self.range_min,
            x=self.mount_x,
            z=self.mount_z,
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def true_ranges(self, world: World, poses: np.ndarray) -> np.ndarray:
        """Noise-free ranges (S x B float32, inf = nothing) ignoring glass: the geometry."""
        origins, headings = self.origins(poses)
        return cast(world, origins, headings, self.geometry().angles, self.range_max).opaque

    def origins(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Laser positions (S x 2) and headings (S,) for robot poses (S x 3)."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        xy = poses[:, :2] + self.mount_x * np.stack([c, s], axis=1)
        return xy, poses[:, 2]

    def measure(
        self,
        world: World,
        poses: np.ndarray,
        rng: np.random.Generator,
        progress: Callable[[int], object] | None = None,
    ) -> np.ndarray:
        """Simulated readings (S x B float32, NaN = no return) from robot poses (S x 3)."""
        origins, headings = self.origins(poses)
        angles = self.geometry().angles
        hits = cast(world, origins, headings, angles, self.range_max, progress=progress)
        r = hits.opaque.astype(np.float64)

        near_normal = hits.glass_cos >= np.cos(np.deg2rad(self.glass_normal_deg))
        glass_hit = np.isfinite(hits.glass)
        reflect = glass_hit & near_normal
        returns = rng.random(r.shape) < self.glass_return_prob
        weak = hits.glass + rng.normal(0.0, self.glass_sigma, r.shape)
        r = np.where(reflect, np.where(returns, weak, np.inf), r)

        r = r + rng.normal(0.0, self.range_sigma, r.shape)
        r = self._mixed_pixels(r, hits.opaque_id, rng)

        res = self.resolution
        r = np.round(r / res) * res
        bad = ~np.isfinite(r) | (r >= self.range_max) | (r < self.range_min)
        return np.where(bad, np.nan, r).astype(np.float32)

    def _mixed_pixels(
        self, r: np.ndarray, objects: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """At depth edges (neighbours on different objects, ranges apart by more than
        `mixed_jump`), the far-side beam reads between foreground and background."""
        left, right = r[:, :-1], r[:, 1:]
        finite = np.isfinite(left) & np.isfinite(right)
        other = objects[:, :-1] != objects[:, 1:]
        with np.errstate(invalid="ignore"):
            edge = finite & other & (np.abs(right - left) > self.mixed_jump)
        edge &= rng.random(edge.shape) < self.mixed_prob
        u = rng.random(edge.shape)
        near, far = np.minimum(left, right), np.maximum(left, right)
        with np.errstate(invalid="ignore"):
            mixed = near + u * (far - near)
        out = r.copy()
        rows, cols = np.nonzero(edge)
        far_is_right = right[rows, cols] > left[rows, cols]
        out[rows, cols + far_is_right] = mixed[rows, cols]
        return out
