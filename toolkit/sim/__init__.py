"""The simulator: scenarios with known truth, for testing and measuring everything else.

    from toolkit.sim import simulate
    sim = simulate("corridor", seed=0)        # the paper's corridor: 2000 scans, 8 sections
    sim.dataset                               # Dataset: t, ranges (S x 181, NaN = no return),
                                              #   laser geometry, odometry, groundtruth
    sim.labels, sim.regions, sim.sections     # true place per scan, training regions, sections

Parameters (keyword arguments of `simulate`, options of `toolkit simulate`): the scenario's
`scans`, `speed` (m/s), `turn_rate` (rad/s), `t0` (s); `sway` (rad, 0: none) and `sway_period`
(s), a hand-held scanner's heading swept side to side about the path's; every field of `LaserModel`
(toolkit/sim/laser.py) and of `OdometryModel` (toolkit/sim/odometry.py). Everything random
draws from one numpy Generator seeded by `seed`: the same seed gives the same log.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import pandas as pd
from rich.progress import TaskID

from toolkit.dataset import Dataset, ImportReport, make_meta, path_distance, pose_frame
from toolkit.errors import ToolkitError
from toolkit.progress import task
from toolkit.sim.geometry import World
from toolkit.sim.laser import LaserModel
from toolkit.sim.odometry import OdometryModel
from toolkit.sim.procedural import random_world
from toolkit.sim.scenarios import SCENARIOS as FIXED_SCENARIOS
from toolkit.sim.scenarios import Scenario, building, sample_path
from toolkit.sim.truth import REGION_PARTS, training_regions
from toolkit.sim.truth import sections as _sections
from toolkit.typed import convert, field_types

__all__ = [
    "SCENARIOS",
    "LaserModel",
    "OdometryModel",
    "Simulation",
    "parameters",
    "simulate",
]

PATH_PARAMS: dict[str, type] = {"scans": int, "speed": float, "turn_rate": float, "t0": float}
SWAY_PERIOD = 4.0  # s: one sweep left and right of a hand-held scanner's `sway`
# "random": a new world per seed (toolkit/sim/procedural.py), its parameter `route` the path
SCENARIOS: dict[str, Any] = {**FIXED_SCENARIOS, "random": random_world}


@dataclass
class Simulation:
    """A simulated log and its truth."""

    dataset: Dataset  # scans, laser geometry, odometry (drifting), groundtruth (true poses)
    labels: np.ndarray  # (S,) str: true place label per scan ("none" where no feature)
    regions: pd.DataFrame  # feature, start, end (timestamps, inclusive): 10 scans per feature
    sections: np.ndarray  # (S,) int: section 0..7 of the corridor (paper Table 1), else -1
    scenario: str = ""
    seed: int = 0
    params: dict[str, Any] = field(default_factory=dict)  # every model parameter used
    world: World | None = None

    def head(self, n: int) -> Simulation:
        """The first `n` scans, with their truth (regions re-chosen within them)."""
        return self.take(np.arange(min(n, self.dataset.n_scans)), head=n)

    def take(self, index: np.ndarray, **note: float) -> Simulation:
        """The scans at `index` (ascending), with their truth (regions re-chosen within them,
        by the true path); `note` joins the dataset's meta and the parameters."""
        ds = self.dataset
        t = ds.t[index]
        cut = Dataset(
            t=t,
            ranges=ds.ranges[index],
            laser=ds.laser,
            odometry=None
            if ds.odometry is None
            else ds.odometry.iloc[index].reset_index(drop=True),
            groundtruth=None
            if ds.groundtruth is None
            else ds.groundtruth.iloc[index].reset_index(drop=True),
            meta={**ds.meta, **note},
        )
        return dataclasses.replace(
            self,
            dataset=cut,
            labels=self.labels[index],
            regions=training_regions(t, self.labels[index], along=self.distance()[index]),
            sections=self.sections[index],
            params={**self.params, **note},
        )

    def distance(self) -> np.ndarray:
        """Per scan, the true distance driven since the first scan (m)."""
        gt = self.dataset.groundtruth
        assert gt is not None
        return path_distance(gt[["x", "y"]].to_numpy())

    def truth(self) -> pd.DataFrame:
        """Per scan: t, true x, y, theta, label, section (what truth.parquet holds)."""
        gt = self.dataset.groundtruth
        assert gt is not None
        frame = gt.copy()
        frame["label"] = self.labels
        frame["section"] = self.sections
        return frame


#: A simulator parameter's value (`-p NAME=VALUE`).
Param = bool | int | float | str


def parameters(
    scenario: str, seed: int = 0, **params: Param
) -> tuple[Scenario, LaserModel, OdometryModel]:
    """The scenario and the models with `params` applied. Each parameter is checked against
    the models' dataclass fields and converted to the field's type (text from `-p KEY=VALUE`
    or JSON values); an unknown name or a wrong type is a one-line error. The random
    scenario's world is drawn from `seed`, its path from the parameter `route` (0 or 1); the
    building's `laps` drives its ring that many times."""
    if scenario not in SCENARIOS:
        raise ToolkitError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
    route = params.pop("route", None)
    if route is not None and scenario != "random":
        raise ToolkitError("route is a parameter of the random scenario only")
    way = cast(int, convert(route, int, "route", "the simulator")) if route is not None else 0
    entered = params.pop("entered", None)
    if entered is not None and scenario != "random":
        raise ToolkitError("entered is a parameter of the random scenario only")
    enter = _yes(entered) if entered is not None else False
    brief = params.pop("brief", None)
    if brief is not None and scenario != "random":
        raise ToolkitError("brief is a parameter of the random scenario only")
    short = _yes(brief, "brief") if brief is not None else False
    if short and not enter:
        raise ToolkitError("brief (short room visits) needs entered")
    revisit = params.pop("revisit", None)
    if revisit is not None and scenario != "random":
        raise ToolkitError("revisit is a parameter of the random scenario only")
    back = _yes(revisit, "revisit") if revisit is not None else False
    laps = params.pop("laps", None)
    if laps is not None and scenario != "building":
        raise ToolkitError("laps is a parameter of the building scenario only")
    rounds = cast(int, convert(laps, int, "laps", "the simulator")) if laps is not None else 1
    if rounds < 1:
        raise ToolkitError(f"laps must be at least 1, not {rounds}")
    if scenario == "random":
        scn = random_world(seed, way, enter, short, back)
    elif scenario == "building":
        scn = building(rounds)
    else:
        scn = SCENARIOS[scenario]()
    laser_fields = field_types(LaserModel)
    odo_fields = field_types(OdometryModel)
    kinds = {**PATH_PARAMS, **laser_fields, **odo_fields}
    unknown = sorted(set(params) - set(kinds))
    if unknown:
        known = ", ".join(sorted(kinds))
        raise ToolkitError(f"unknown simulator parameter(s) {unknown}; known: {known}")
    typed: dict[str, Any] = {
        k: convert(v, kinds[k], k, "the simulator") for k, v in params.items() if v is not None
    }
    for name in PATH_PARAMS:
        if name in typed:
            setattr(scn, name, typed[name])
    if scn.scans < 2:
        raise ToolkitError(f"scans must be at least 2, not {scn.scans}")
    if scn.speed <= 0 or scn.turn_rate <= 0:
        raise ToolkitError("speed and turn_rate must be positive")
    laser_args = {**scn.laser, **{k: v for k, v in typed.items() if k in laser_fields}}
    odo_args = {k: v for k, v in typed.items() if k in odo_fields}
    return scn, LaserModel(**laser_args), OdometryModel(**odo_args)


def _yes(value: Param, name: str = "entered") -> bool:
    return bool(convert(value, bool, name, "the simulator"))


def _sway(params: dict[str, Param]) -> tuple[float, float]:
    """`sway` (rad) and `sway_period` (s), taken out of `params` and checked."""
    amp, period = params.pop("sway", None), params.pop("sway_period", None)
    sway = cast(float, convert(amp, float, "sway", "the simulator")) if amp is not None else 0.0
    every = SWAY_PERIOD
    if period is not None:
        every = cast(float, convert(period, float, "sway_period", "the simulator"))
    if sway < 0 or every <= 0:
        raise ToolkitError("sway must be at least 0 and sway_period positive")
    return float(sway), float(every)


def simulate(scenario: str, seed: int = 0, **params: Param) -> Simulation:
    """Simulate `scenario` ("corridor", "building" or "random") with the models' parameters
    `params` (for "random", also `route`: 0 or 1, the path through the world of `seed`, and
    `entered`: true for a path that also enters rooms, and `brief`: with it, small rooms
    entered briefly, and `revisit`: a path that comes back to its start; for "building",
    `laps`: times round the ring)."""
    sway, period = _sway(params)
    scn, laser, odometry = parameters(scenario, seed, **params)
    rng = np.random.default_rng(seed)
    truth, times = sample_path(scn.waypoints, scn.scans, scn.speed, scn.turn_rate)
    if sway > 0:  # a hand-held scanner: turning fast (peak sway * 2 pi / period rad/s) all along
        truth[:, 2] += sway * np.sin(2.0 * np.pi * times / period)
    t = np.round(scn.t0 + times, 3)  # whole ms: every format (ARIA prints ms) keeps t exactly
    with task(f"simulate {scenario}", total=len(truth)) as (bar, job):
        ranges = laser.measure(scn.world, truth, rng, lambda n: bar.advance(TaskID(job), n))
    odo = odometry.integrate(truth, rng)
    labels = scn.labels(laser.origins(truth)[0])  # what the scanner has beside it
    regions = training_regions(
        t, labels, along=path_distance(truth[:, :2]), parts=scn.region_parts or REGION_PARTS
    )
    used = {
        **{k: getattr(scn, k) for k in PATH_PARAMS},
        **({"route": int(params.get("route") or 0)} if scenario == "random" else {}),
        **({"entered": True} if _yes(params.get("entered") or False) else {}),
        **({"brief": True} if _yes(params.get("brief") or False, "brief") else {}),
        **({"revisit": True} if _yes(params.get("revisit") or False, "revisit") else {}),
        **({"laps": int(params.get("laps") or 1)} if scenario == "building" else {}),
        **({"sway": sway, "sway_period": period} if sway > 0 else {}),
        **laser.to_dict(),
        **odometry.to_dict(),
        "rate_hz": float((len(t) - 1) / (t[-1] - t[0])),
    }
    report = ImportReport(records_read=len(t), records_kept=len(t))
    report.note(f"simulated {scenario} (seed {seed})")
    meta = make_meta(
        "simulated",
        [],
        laser.geometry(),
        report,
        time_source="simulated",
        simulation={"scenario": scenario, "seed": seed, "params": used},
    )
    ds = Dataset(
        t=t,
        ranges=ranges,
        laser=laser.geometry(),
        odometry=pose_frame(t, odo),
        groundtruth=pose_frame(t, truth),
        meta=meta,
    )
    return Simulation(
        dataset=ds,
        labels=labels,
        regions=regions,
        sections=_sections(len(t), scn.sections),
        scenario=scenario,
        seed=seed,
        params=used,
        world=scn.world,
    )
