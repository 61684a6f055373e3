"""The Intel Research Lab log (real, CARMEN, SLAM-corrected poses): places taught from the
spans in datasets/real-regions/intel-regions.csv (two corridor stretches, two rooms), found
along the whole log. The log has no place labels; the check is geometric: scans taken where
the corrected pose is on the corridor ring must score higher for "corridor" than scans taken
inside the rooms, and the other way round."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
REGIONS = ROOT / "datasets" / "real-regions" / "intel-regions.csv"

pytestmark = pytest.mark.real


def place_by_position(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """corridor / room / other from the corrected pose (the lab's ring corridor, by the map)."""
    ring = (
        ((np.abs(x - 12.6) < 1.0) & (y > -19.5) & (y < 0.5))
        | ((np.abs(x + 5.6) < 1.0) & (y > -19.5) & (y < 0.5))
        | ((np.abs(y + 18.9) < 0.9) & (x > -7) & (x < 14))
        | ((np.abs(y - 0.1) < 0.9) & (x > -7) & (x < 14))
        | ((np.abs(x + 1.4) < 0.7) & (y > -18) & (y < 0))
    )
    room = ~ring & ((y > 1.2) | (y < -20) | (x > 14) | (x < -7.2))
    return np.where(ring, "corridor", np.where(room, "room", "other"))


def test_intel_corridor_and_room(real: Path, tmp_path: Path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    from toolkit.app.cli import main

    log = real / "carmen_radish_corrected" / "intel-corrected.log.gz"
    data, run = tmp_path / "intel", tmp_path / "run"
    for args in (
        ["import", "carmen", str(log), "--out", str(data), "-O", "poses=groundtruth", "-q"],
        ["label", str(data), "--regions", str(REGIONS), "--out", str(run)],
    ):
        monkeypatch.setattr(sys, "argv", ["toolkit", *args])
        try:
            main()
        except SystemExit as e:
            assert not e.code, capsys.readouterr().err
    labels = pd.read_parquet(run / "labels.parquet")
    metrics = json.loads((run / "labels-metrics.json").read_text())
    assert metrics["poses"] == "groundtruth" and metrics["classes"] == ["corridor", "room", "none"]
    model = json.loads((run / "model.json").read_text())
    spans = model["training_spans"]
    assert [s["feature"] for s in spans] == ["corridor", "corridor", "room", "room"]
    assert all(s["scans"] == 10 for s in spans)

    truth = pd.read_parquet(data / "groundtruth.parquet")
    x = np.interp(labels["t"], truth["t"], truth["x"])
    y = np.interp(labels["t"], truth["t"], truth["y"])
    place = place_by_position(x, y)
    trained = np.zeros(len(labels), dtype=bool)
    for s in spans:
        trained |= (labels["t"] >= s["start"] - 1e-6) & (labels["t"] <= s["end"] + 1e-6)
    assert trained.sum() == 40
    # the training scans themselves are found
    for s in spans:
        inside = (labels["t"] >= s["start"] - 1e-6) & (labels["t"] <= s["end"] + 1e-6)
        assert (labels.loc[inside, "label"] == s["feature"]).mean() >= 0.8
    # elsewhere: each feature is found more often, and is more probable, at its kind of place
    test = ~trained
    corridor, room = test & (place == "corridor"), test & (place == "room")
    assert corridor.sum() > 300 and room.sum() > 100

    def found(feature: str, where: np.ndarray) -> float:
        return float((labels.loc[where, "label"] == feature).mean())

    # the log's scans are about 1 m of path apart: the context (1 m either side) would hold
    # the neighbouring places, so the default learns without it here, with the local map
    # over 2 m of path instead (the fit report says so). The corridor is found in 0.82 of
    # its scans (the target 0.8; 0.798 without session 31's second classifier, 0.693
    # without session 29's view ahead, 0.611 without session 28's pooled revisits too, 0.584
    # without session 27's pooled turn too, which the next lines check; without the local
    # map 0.43, with the context forced on 0.18; the last default 0.48: docs/places.md), and
    # in 0.17 of the rooms'
    assert model["config"]["context"] == 0.0 and model["fit_report"]["context"].startswith("off")
    assert model["config"]["local_map"] == 2.0
    # nor the taught scans' opened copies (one corridor scan's copy, its door opened on both
    # sides, took the rooms to 0.793: docs/journal/places.md, session 13)
    assert model["config"]["augment_open"] == 0.0
    assert "no opened copies" in model["fit_report"]["context"]
    # and the HMM's dwell of two stages (`sparse_dwell_stages`): on random worlds thinned to
    # 1 m it lowered ECE by 0.01-0.02; here the rooms 0.815 -> 0.832, the corridor unchanged
    # (docs/journal/places.md, session 23)
    assert model["config"]["dwell_stages"] == 2
    assert model["config"]["turn_pool"] == 0.3 and model["config"]["turn_pool_door"] == 2
    # and its junctions' turns take the other laps' evidence within 4 m cells (session 28,
    # space28), and a junction's long turn (7 scans or more, two ways out) is pooled beside an
    # enclosed turn: all 8 of the corridor's long turns, none of the rooms' (session 28, junc28)
    assert model["config"]["place_pool"] == 4.0
    assert model["config"]["place_pool_into"] == "junctions"
    assert model["config"]["turn_pool_junction"] == 7
    # and its trees take the view ahead too (`sparse_view_ahead`, session 29, axis29): the
    # end points' major axis and the ranges' spread tell a corridor seen across from a
    # junction's turn from a room, which the place's own columns do not
    assert model["config"]["view_ahead"]
    # and the turns that see far also take a second classifier, without the view ahead's
    # near bins, the mean of the two (session 31's default, near30 and avg30)
    assert model["config"]["view_ahead_near_enclosed"]
    assert model["config"]["view_ahead_near_average"]
    # measured 0.819 (0.798 with one classifier, 0.693 without the view ahead; 0.689 without
    # the junction rule too, 0.615 without the revisits, 0.611 without either, 0.584 without
    # the pooled turn): issue 16's target
    assert found("corridor", corridor) >= 0.8
    assert found("corridor", corridor) > 2.5 * found("corridor", room)
    assert found("room", room) >= 0.8  # issue 16's target (measured 0.870; 0.832 before
    # session 29, 0.815 before session 23)
    assert labels.loc[corridor, "p_corridor"].mean() > labels.loc[room, "p_corridor"].mean()
    assert labels.loc[room, "p_room"].mean() > labels.loc[corridor, "p_room"].mean()
    assert (run / "membership.png").stat().st_size > 10_000

    # --none-model surroundings lets the spans choose the lateral weight: on this lab, where a
    # corridor is told from a room by its long view ahead, they keep all beams alike (the
    # simulator's spans, where places are beside the robot, choose 2: test_targets.py)
    import toolkit
    from toolkit.features import fit, read_regions, training_indices
    from toolkit.features.model import SURROUNDINGS

    ds = toolkit.load(data)
    spans_ = read_regions(REGIONS, ds.t)
    chosen = fit(ds.ranges, ds.laser, training_indices(spans_), SURROUNDINGS, spans_)
    scores = chosen.fit_report["lateral_scores"]
    assert chosen.config.lateral_weight == 0.0 and scores["0"] > max(scores["1"], scores["2"])

    # with the context forced on (1 m either side, one to three scans here), the corridor is
    # mostly called "room"
    from toolkit.features import Config, classify, fitting

    assert ds.groundtruth is not None
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    monkeypatch.setattr(fitting, "MIN_CONTEXT_SCANS", 0)
    forced = fit(ds.ranges, ds.laser, training_indices(spans_), Config(), spans_, poses)
    assert forced.config.context == 1.0
    at = place_by_position(poses[:, 0], poses[:, 1])
    taught = np.zeros(ds.n_scans, dtype=bool)
    taught[np.concatenate(list(training_indices(spans_).values()))] = True
    label = classify(forced, ds.ranges, poses).label
    # (0.18; 0.31 with the opened copies, which a forced context lets in: session 13; 0.48
    # without the no-returns ahead, session 14, rooms 0.84: still below the default's 0.57)
    assert np.mean(label[~taught & (at == "corridor")] == "corridor") < 0.55
    assert np.mean(label[~taught & (at == "room")] == "room") >= 0.8

    # the expert setting that describes the view ahead too (`Config(view_ahead=True)`): on
    # this lab, whose corridor is told from its rooms by the long view, the corridor is found
    # in 0.67 of its scans (rooms 0.87); on random worlds, dense or thinned to this log's
    # 1 m, it loses (docs/journal/places.md, session 13), so it is not the default
    monkeypatch.setattr(fitting, "MIN_CONTEXT_SCANS", 3)
    ahead = fit(
        ds.ranges, ds.laser, training_indices(spans_), Config(view_ahead=True), spans_, poses
    )
    label = classify(ahead, ds.ranges, poses).label
    assert np.mean(label[~taught & (at == "corridor")] == "corridor") > 0.65
    assert np.mean(label[~taught & (at == "room")] == "room") >= 0.8
