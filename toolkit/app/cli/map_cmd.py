"""`toolkit map DATASET --out RUN [--method ...] [--voxel M] [--scheduler none|local:N|ADDRESS]`,
or `toolkit map DATASET... --out DIR` (several datasets, a fleet's tree, a quoted glob)."""

from __future__ import annotations

import glob
import importlib
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from toolkit.app.cli import app
from toolkit.app.cli.options import report_outcomes
from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from toolkit.mapping import Settings

#: keys of a run's config.json that record the run, not settings: read from --config and
#: left out (--method and --voxel say the method and the voxel size)
RECORDED = ("dataset", "created", "laser", "dataset_meta_sha256", "method", "voxel")
#: ... and of its "matcher": which front end and ICP's fixed parameters
RECORDED_MATCHER = ("front_end", "icp", "max_distance")


@app.command("map", short_help="Align the scans; trajectory, maps and metrics.")
def map_command(
    datasets: Annotated[
        list[Path],
        typer.Argument(
            metavar="DATASET",
            help="a dataset directory; or several, a directory tree of them (a fleet), or a "
            "quoted glob: then OUT gets one run per dataset",
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out", metavar="DIR", help="run directory to write (many datasets: their parent)"
        ),
    ],
    method: Annotated[
        str,
        typer.Option(
            metavar="METHOD",
            help="gaussian (the paper's scan matcher), icp (2D point-to-line), "
            "icp-point (Open3D point-to-point) or odometry",
        ),
    ] = "gaussian",
    loops: Annotated[
        bool,
        typer.Option(
            "--loops/--no-loops",
            help="match each scan against a local map (with odometry) and close loops, "
            "optimising the pose graph (GTSAM); a log without odometry is matched "
            "scan-to-keyframe with a constant-velocity motion model. --method gaussian "
            "--no-loops is the paper's scan-to-keyframe matching",
        ),
    ] = True,
    voxel: Annotated[
        float,
        typer.Option(
            metavar="M", help="voxel size (m) to downsample cloud.ply/.pcd; 0 keeps every return"
        ),
    ] = 0.0,
    force: Annotated[bool, typer.Option("--force", help="replace an existing run")] = False,
    scheduler: Annotated[
        str,
        typer.Option(
            metavar="WHERE",
            help="where the work runs: none (this process), local or local:N (a Dask "
            "LocalCluster of N workers) or a Dask scheduler's address; one dataset: its scan "
            "pairs (gaussian), many: one task per dataset",
        ),
    ] = "none",
    each: Annotated[
        bool,
        typer.Option(
            "--each",
            help="many datasets (implied by several DATASETs, a tree or a glob): one run each, "
            "OUT/<name below the tree>; failures by name; current runs (of the same inputs and "
            "settings) are skipped",
        ),
    ] = False,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            metavar="JSON",
            help="expert settings (of every dataset), a JSON object: a run's config.json (its "
            "dataset, created, laser, dataset_meta_sha256, method and voxel are ignored: "
            '--method and --voxel say those) or part of one, e.g. {"slam": {"blind_turn": '
            '0}, "matcher": {"edge_grow": 1}}; docs/maps.md',
        ),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            metavar="KEY=VALUE",
            help="an expert setting, repeatable, over --config's: slam.FIELD (SlamConfig; "
            "slam.loop.FIELD, slam.scan_map.FIELD), matcher.FIELD (of the matcher each dataset "
            "runs: scan-to-map's, i.e. slam.scan_map's, with loops, gaussian and odometry, else "
            "MatchConfig's; a key none uses is an error); VALUE is JSON (3, true, [0.1, 0.2]) "
            "or else text",
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no summary")] = False,
) -> None:
    """Align the scans, build the trajectory and the maps, and measure them against ground truth.

    Writes RUN/: config.json, trajectory.parquet, trajectory.tum (evo), cloud.ply and
    cloud.pcd, map.png, map.pgm + map.yaml (ROS map_server), graph.g2o and loops.csv (with
    loops), metrics.json (with each stage's seconds); atomically. With many datasets, OUT/<name>/ for each.
    --config and --set change expert settings, every dataset's alike, matcher.* those of the
    matcher each dataset runs (checked once, before any work); config.json records every
    setting that ran, and a fleet's re-run redoes the runs of other settings.
    Beams that read the robot itself (a short range that stays the same through the
    odometry's turns) are left out and named on the summary line; the line also says when
    the ranges lie beyond any laser's reach (cm or mm). Odometry that stands still while the
    scans move (a stalled encoder, an odometry stream that starts late or stops early) is
    mended from the scans over those scans (mapped as without odometry) and named there too.
    A laser that the scans and the odometry agree is mounted turned round or upside down,
    against what the log says, is read so, and the line says it.
    """
    # on use: the matcher (numba) loads for `map` alone, with loops also the loop
    # closer and GTSAM (`map_run` loads it first thing); no garbage collection meanwhile
    from toolkit.app.startup import imports_kept, numba_tables

    with imports_kept():
        from toolkit.mapping import has_odometry, map_run
        from toolkit.poses import Method

        method = Method.parse(method)
        if loops and method != Method.ODOMETRY:
            importlib.import_module("toolkit.slam.run")
        numba_tables()  # every map run loads kernels (the writers' at least)
    if voxel < 0:
        raise ToolkitError(f"--voxel must be 0 or positive, not {voxel}")
    found = _find(datasets) if each or _many(datasets) else None
    settings: dict[bool, Settings] | None = None  # by odometry; None: the defaults
    if config is not None or set_:  # checked once, before any work (a fleet's too)
        paths = [d for d, _ in found] if found is not None else datasets
        settings = map_settings(config, set_, method, loops, _odometry(paths))
    if found is not None:
        _map_each(found, out, method, voxel, force, scheduler, quiet, loops, settings)
        return
    dataset = datasets[0]
    match_config, slam_config = (
        settings[has_odometry(dataset)] if settings is not None else (None, None)
    )
    if scheduler != "none" and method != Method.GAUSSIAN:
        raise ToolkitError(f"--scheduler runs the gaussian matcher; method {method} runs here only")
    if scheduler == "none":
        run = map_run(
            dataset, out, method, voxel, match_config, force, loops=loops, slam_config=slam_config
        )
    else:
        from toolkit.app.fleet import client_for  # Dask, on use
        from toolkit.app.fleet_map import matcher_for, on_shared_storage
        from toolkit.dataset import SCANS  # with the line above

        with client_for(scheduler) as client:
            scans = dataset / SCANS if on_shared_storage(scheduler) else None
            matcher = matcher_for(client, scans=scans) if client is not None else None
            run = map_run(
                dataset,
                out,
                method,
                voxel,
                match_config,
                force,
                matcher,
                loops,
                slam_config=slam_config,
            )
    if quiet:
        return
    metrics = run.metrics
    line = f"{run.path}: {metrics['scans']} scans by {method}"
    if "loops" in metrics:
        line += f", {metrics['loops']} loops"
    if metrics.get("fixed_beams"):
        from toolkit.beams import beam_spans  # on use: numpy and the dataset's module

        spans = beam_spans(metrics["fixed_beams"])
        line += f", beams {spans} left out (the same range while the rest of the scan changed)"
    if metrics.get("laser_mounting"):
        line += (
            f", the laser read as mounted {metrics['laser_mounting']['read_as']}: the scans and"
            " the odometry agree only so"
        )
    clock = metrics.get("scan_clock")
    if clock:
        from toolkit.slam.motion import jitters  # on use: the mapper has loaded it

        if clock["lost"] or jitters(clock):
            low, high = clock["spread"]
            lost = f"{clock['lost']} scan{'' if clock['lost'] == 1 else 's'} lost"
            line += (
                f", scan times read as whole periods of {clock['period'] * 1e3:.0f} ms"
                f" (stamped {low:.2f}-{high:.2f} of one, {lost})"
            )
    for stall in metrics.get("odometry_stalls", []):
        line += (
            f", odometry still over scans {stall['first']}-{stall['last']} while the scans "
            f"moved {stall['moved_m']:.1f} m: mended from the scans"
        )
    if metrics.get("beyond_reach"):
        line += (
            f", {metrics['beyond_reach']:.0%} of the returns beyond 100 m"
            " (ranges in cm or mm? nothing matched: the map is the odometry's)"
        )
    if metrics.get("pairs_per_second"):
        line += f", {metrics['pairs_per_second']:.0f} pairs/s"
    if metrics.get("groundtruth"):
        ate, rpe, fails = metrics["ate"], metrics["rpe"], metrics["failures"]
        line += (
            f"; ATE {ate['rmse']:.3f} m, RPE {rpe['translation']:.4f} m "
            f"{rpe['rotation_deg']:.3f}°, {fails['count']} failures"
        )
    typer.echo(line)


def map_settings(
    path: Path | None,
    pairs: list[str] | None,
    method: str,
    loops: bool,
    odometry: Collection[bool] = (True, False),
) -> dict[bool, Settings]:
    """The matcher's and the mapper's settings for a dataset with odometry (True) and one
    without (False), of the kinds in `odometry` (this run's datasets): the defaults, then
    --config's, then --set's; the mapper's None when the run has no loops (a slam setting then
    is an error). `matcher.*` goes to the matcher each kind runs (`toolkit.mapping.matcher_of`,
    by the slam settings so far): scan-to-map's (`slam.scan_map`) with loops, gaussian and
    odometry, else the pair matcher's (`MatchConfig`; ICP uses its keyframes only). A key
    that none of them has is an error, as is a run's recorded scan-to-map matcher (its
    `front_end`) when no dataset runs it: a setting is never silently unused."""
    from dataclasses import replace

    from toolkit.align.scan import MatchConfig
    from toolkit.app.settings import apply, parse_sets, read_json
    from toolkit.mapping import SCAN_TO_MAP, matcher_of
    from toolkit.slam.pipeline import SlamConfig

    layers: list[tuple[str, dict[str, Any], str | None]] = []
    if path is not None:
        data = {k: v for k, v in read_json(path).items() if k not in RECORDED}
        tag = None  # a run's config.json: which matcher its "matcher" block is
        if isinstance(data.get("matcher"), dict):
            ran = data["matcher"]
            tag = SCAN_TO_MAP if ran.get("front_end") == SCAN_TO_MAP else None
            drop = RECORDED_MATCHER + (("iterations",) if "icp" in ran else ())  # ICP's own
            data["matcher"] = {k: v for k, v in ran.items() if k not in drop}
        layers.append((str(path), {k: v for k, v in data.items() if v is not None}, tag))
    layers.append(("--set", parse_sets(pairs), None))
    with_loops = loops and method != "odometry"
    states = {o: (MatchConfig(), SlamConfig()) for o in sorted(set(odometry), reverse=True)}
    for source, data, tag in layers:
        unknown = sorted(set(data) - {"matcher", "slam"})
        if unknown:
            raise ToolkitError(
                f"unknown setting {unknown[0]} (settings: slam.*, matcher.*)", file=source
            )
        for key in ("matcher", "slam"):
            if key in data and not isinstance(data[key], dict):
                raise ToolkitError(f"{key}: expected an object of settings", file=source)
        if "slam" in data:
            if not with_loops:
                raise ToolkitError(
                    "slam.*: the mapper's settings need loops (not --no-loops, --method odometry)",
                    file=source,
                )
            for o, (match, slam) in states.items():
                states[o] = (match, apply(slam, data["slam"], source, "slam."))
        if not data.get("matcher"):
            continue
        block: dict[str, Any] = data["matcher"]
        used: set[str] = set()
        runs: dict[bool, str] = {}  # the matcher of each kind of dataset that takes the block
        for o, (match, slam) in states.items():
            target = matcher_of(method, loops, slam, o)
            if target is None or (tag == SCAN_TO_MAP and target != SCAN_TO_MAP):
                continue
            runs[o] = target
            mine = {k: v for k, v in block.items() if k in _fields(target)}
            used |= mine.keys()
            if target == SCAN_TO_MAP:
                scan_map = apply(slam.scan_map, mine, source, "matcher.")
                states[o] = (match, replace(slam, scan_map=scan_map))
            else:
                states[o] = (apply(match, mine, source, "matcher."), slam)
        unused = [k for k in block if k not in used]
        if unused:
            raise _unused(unused[0], block, runs, tag, method, with_loops, source)
    return {o: (match, slam if with_loops else None) for o, (match, slam) in states.items()}


#: the sequential matchers (`toolkit.mapping.matcher_of`) in messages
MATCHERS = {
    "scan-to-map": "the scan-to-map matcher (slam.scan_map)",
    "pairs": "the pair matcher (MatchConfig)",
    "icp": "ICP (of MatchConfig: keyframe_distance, keyframe_angle)",
}


def _fields(matcher: str) -> set[str]:
    """The settings `matcher` (a `matcher_of` name) uses."""
    from toolkit.align.scan import MatchConfig
    from toolkit.slam.scanmap import MapConfig
    from toolkit.typed import field_types

    if matcher == "icp":
        return {"keyframe_distance", "keyframe_angle"}
    return set(field_types(MapConfig if matcher == "scan-to-map" else MatchConfig))


def _unused(
    key: str,
    block: dict[str, Any],
    runs: dict[bool, str],
    tag: str | None,
    method: str,
    with_loops: bool,
    source: str,
) -> ToolkitError:
    """The one-line error for `matcher.KEY` that no matcher of this run uses (`runs`: the
    matcher of each kind of dataset, by odometry, that took the block; a key of either
    matcher is used when both run)."""
    from toolkit.align.scan import MatchConfig
    from toolkit.app.settings import apply
    from toolkit.slam.scanmap import MapConfig

    if method == "odometry":
        return ToolkitError("matcher.*: --method odometry matches no scans", file=source)
    if tag == "scan-to-map" and not runs:
        return ToolkitError(
            "matcher: a scan-to-map run's (its front_end), and no dataset of this run is "
            "matched scan-to-map (loops, gaussian and odometry): leave it out to use the rest",
            file=source,
        )
    ran = MATCHERS[next(iter(runs.values()))]  # one matcher: when both run, each key is used
    if with_loops and method == "gaussian" and set(runs) == {False}:
        ran += ", the dataset having no odometry"
    order = ("pairs", "scan-to-map") if "icp" in runs.values() else ("scan-to-map", "pairs")
    owners = [m for m in order if key in _fields(m)]
    if owners:
        return ToolkitError(
            f"matcher.{key}: a setting of {MATCHERS[owners[0]]}, which this run does not "
            f"use (it runs {ran})",
            file=source,
        )
    target = next(iter(runs.values()))
    settings = MapConfig() if target == "scan-to-map" else MatchConfig()
    try:  # an unknown key: apply's one line, with a near key
        apply(settings, {key: block[key]}, source, "matcher.")
    except ToolkitError as e:
        return e
    return ToolkitError(f"unknown setting matcher.{key} (this run runs {ran})", file=source)


def _many(datasets: list[Path]) -> bool:
    """Several inputs, a glob pattern, or a directory that is not itself a dataset."""
    from toolkit.dataset import is_dataset_dir  # on use: the dataset module loads pyarrow

    if len(datasets) != 1:
        return True
    one = datasets[0]
    if not one.exists():
        return glob.has_magic(str(one))
    return one.is_dir() and not is_dataset_dir(one)


def _find(datasets: list[Path]) -> list[tuple[Path, Path]]:
    """The datasets of a fleet's inputs, with their run names (`find_datasets`)."""
    from toolkit.app.fleet import find_datasets  # Dask, on use

    found = find_datasets(datasets)
    if not found:
        raise ToolkitError("no dataset found in the inputs (a dataset directory has meta.json)")
    return found


def _odometry(datasets: list[Path]) -> set[bool]:
    """Whether the datasets have odometry, each kind present once (a path that is no dataset:
    either, as map_run will say)."""
    from toolkit.dataset import is_dataset_dir
    from toolkit.mapping import has_odometry

    kinds = {has_odometry(d) if is_dataset_dir(d) else None for d in datasets}
    return {True, False} if None in kinds else {k for k in kinds if k is not None}


def _map_each(
    found: list[tuple[Path, Path]],
    out: Path,
    method: str,
    voxel: float,
    force: bool,
    scheduler: str,
    quiet: bool,
    loops: bool = True,
    settings: dict[bool, Settings] | None = None,
) -> None:
    """One run per dataset (with loops or not and the settings of its matcher, as one
    dataset's run); a line per failure on stderr and exit 1 if any failed."""
    from toolkit.app.fleet import client_for  # Dask, on use
    from toolkit.app.fleet_map import map_many, on_shared_storage

    with client_for(scheduler) as client:
        shared = on_shared_storage(scheduler)
        outcomes = map_many(client, found, out, method, voxel, force, shared, loops, settings)
    report_outcomes(outcomes, out, "datasets", quiet)
