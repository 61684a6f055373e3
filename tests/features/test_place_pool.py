"""A place's evidence pooled by position over the whole log (`Config.place_pool`,
`classify.pool_places`): the scans taken at the same spot on other passes, at any time and
heading, share their evidence before the HMM."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from toolkit.errors import ToolkitError
from toolkit.features import Config
from toolkit.features.classify import evidence_weights, pool_places, turn_groups


def _brute_force(config: Config, scores: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """`pool_places` written out scan by scan: the neighbours in the 3 x 3 cells around, less
    the run of consecutive scans around the scan that stays among them (its own pass)."""
    n, r = len(scores), config.place_pool
    valid = np.isfinite(poses[:, :2]).all(axis=1)
    cell = np.floor(np.nan_to_num(poses[:, :2]) / r).astype(int)
    group = turn_groups(poses, 0.3)
    mean = np.array([scores[group == group[i]].mean(axis=0) for i in range(n)])
    weight = evidence_weights(replace(config, turn_length=0.0), n, poses) * valid
    out = scores.copy()
    for i in np.flatnonzero(valid):
        near = valid & (np.abs(cell - cell[i]) <= 1).all(axis=1)
        a = b = i
        while a > 0 and near[a - 1]:
            a -= 1
        while b < n - 1 and near[b + 1]:
            b += 1
        near[a : b + 1] = False
        w, s = weight[near].sum(), config.place_pool_share
        out[i] = (scores[i] + s * (weight[near, None] * mean[near]).sum(axis=0)) / (1 + s * w)
    return out


def test_pooled_by_position_as_written_out_scan_by_scan() -> None:
    """A random walk folded into a 5 m square (it comes back to its spots many times), with a
    turn on the spot and two scans without a pose: the vectorised pooling equals the scan by
    scan one, the scans without a pose keep their own evidence, and the others change."""
    rng = np.random.default_rng(1)
    n = 300
    poses = np.c_[np.cumsum(rng.normal(0, 0.4, (n, 2)), axis=0) % 5.0, rng.uniform(-3, 3, n)]
    poses[50:60, :2] = poses[49, :2]  # a turn on the spot
    poses[[7, 100], :2] = np.nan
    scores = np.log(rng.dirichlet(np.ones(3), n))
    config = Config(place_pool=0.7, place_pool_share=0.8, place_pool_into="all")
    out = pool_places(config, scores, poses)
    assert np.allclose(out, _brute_force(config, scores, poses), rtol=0, atol=1e-12)
    assert np.array_equal(out[[7, 100]], scores[[7, 100]])
    assert (np.abs(out - scores).max(axis=1) > 1e-6).mean() > 0.9
    # one scan 5 km away: more cells than 4 per scan, the occupied cells alone looked up
    # (np.unique), not a grid; the same pooling
    far = poses.copy()
    far[150, :2] = 5000.0
    config = Config(place_pool=0.7, place_pool_share=0.8, place_pool_into="all")
    assert np.allclose(pool_places(config, scores, far), _brute_force(config, scores, far))


def _turned_then_driven_through() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses and scores of a spot turned in on the way out (eight headings that look like a
    room) and driven through on the way back (0.5 m steps that say corridor); and the two
    scores."""
    out_way = np.c_[np.arange(0.0, 5.0), np.zeros(5), np.zeros(5)]
    turn = np.c_[np.full(8, 5.0), np.zeros(8), np.arange(8) * 0.5]
    back = np.c_[np.arange(7.25, 0.0, -0.5), np.full(15, 0.1), np.full(15, np.pi)]
    poses = np.r_[out_way, turn, back]
    corridor, room = np.log([0.8, 0.2]), np.log([0.2, 0.8])
    scores = np.r_[np.tile(corridor, (5, 1)), np.tile(room, (8, 1)), np.tile(corridor, (15, 1))]
    return poses, scores, corridor, room


def test_a_turn_passed_again_driving_takes_the_drive_s_evidence() -> None:
    """A corridor spot turned in on the way out (eight headings that look like a room) and
    driven through on the way back (0.5 m steps that say corridor): pooled at 0.5 m, the
    turn's scans take the three scans of the drive past within a cell and lean to the
    corridor; the turn counts once (its mean, its arrival's step) for the drive past, not
    eight times; a spot passed once is unchanged; off (0) nothing changes."""
    poses, scores, corridor, room = _turned_then_driven_through()
    config = Config(place_pool=0.5, place_pool_into="all")
    out = pool_places(config, scores, poses)
    assert np.allclose(out[5:13], (room + 3 * corridor) / 4)  # x 5.75, 5.25, 4.75 on the way back
    assert (out[5:13, 0] > out[5:13, 1]).all()
    drive_by = 13 + 4  # the way back's scan at x 5.25
    assert np.allclose(out[drive_by], (corridor + room) / 2)  # the turn once, weight 1
    assert np.array_equal(out[13], scores[13])  # x 7.25: no other pass within a cell
    assert np.array_equal(out[:4], scores[:4])
    assert np.allclose(out, _brute_force(config, scores, poses))
    assert np.array_equal(pool_places(Config(), scores, poses), scores)
    assert np.array_equal(pool_places(config, scores, None), scores)


def test_only_a_far_seeing_turn_away_from_doorways_takes_it_by_default() -> None:
    """The same spot with ranges: by default ("junctions") only the turn's scans take the
    drive past's evidence, and only while the turn sees past `turn_pool_reach` (6 m) and no
    enclosed turn is among the two before or after it; "far" gives it to the drive past too
    (a turn of one scan that sees far); without ranges nothing is pooled but with "all"."""
    poses, scores, _, _ = _turned_then_driven_through()
    far = np.full((len(poses), 20), 9.0)  # every scan sees 9 m
    config = Config(place_pool=0.5)
    assert config.place_pool_into == "junctions"
    everyone = pool_places(replace(config, place_pool_into="all"), scores, poses)
    out = pool_places(config, scores, poses, far)
    assert np.array_equal(out[5:13], everyone[5:13])  # the turn takes the drive past's
    assert np.array_equal(np.delete(out, np.s_[5:13], 0), np.delete(scores, np.s_[5:13], 0))
    assert np.array_equal(
        pool_places(replace(config, place_pool_into="far"), scores, poses, far), everyone
    )
    near = far.copy()
    near[5:13] = 3.0  # the turn sees no farther than 3 m: enclosed, its own
    assert np.array_equal(pool_places(config, scores, poses, near), scores)
    doorway = far.copy()
    doorway[3] = 3.0  # an enclosed scan two turns before it: a doorway's turn, its own
    assert np.array_equal(pool_places(config, scores, poses, doorway)[5:13], scores[5:13])
    assert np.array_equal(pool_places(config, scores, poses), scores)  # no ranges


def test_place_pool_is_off_by_default_and_checked() -> None:
    """Off by default (a model saved before has no field: off, as it was); a negative radius
    or share is refused."""
    assert Config().place_pool == 0.0
    assert Config.from_dict({}).place_pool == 0.0
    for bad in ({"place_pool": -1.0}, {"place_pool_share": -0.5}, {"place_pool_into": "some"}):
        with pytest.raises(ToolkitError):
            Config(**bad)  # type: ignore[arg-type]


def test_a_revisit_world_s_junction_turns_found_by_the_other_pass() -> None:
    """On seed 4's brief world whose path comes back along the chain (`--revisit`; a
    development seed), the default (`sparse_place_pool` 4, junctions) finds more of the
    corridor's scans taken turning on the spot than session 27's default (place_pool 0) in
    runs a and b, and the rooms (and their short stays) exactly as many (measured, runs a /
    b: the turning scans 0.18 / 0.10 -> 0.28 / 0.17, rooms 0.78 / 0.79 and short stays 0.25 /
    0.29 both; measured on session 28's default, without session 29's view ahead)."""
    from tests.features.test_sparse_protocol import BASE28, found_shares, gt_poses
    from toolkit.features.evaluate import worlds
    from toolkit.features.fitting import fit
    from toolkit.features.regions import spans_from_frame, training_indices

    runs = worlds(4, 1.0, 0.5, entered=True, brief=True, revisit=True)
    a = runs["a"]
    spans = spans_from_frame(a.regions, a.dataset.t)
    taught = training_indices(spans)
    model = fit(a.dataset.ranges, a.dataset.laser, taught, BASE28, spans, gt_poses(a))
    assert model.config.place_pool == 4.0  # a sparse log: the default's revisits pooled
    models = {"now": model, "before": replace(model, config=replace(model.config, place_pool=0.0))}
    for key in "ab":
        found = found_shares(models, runs[key], taught if key == "a" else None)
        assert found["turns"]["now"] > found["turns"]["before"] + 0.05
        assert found["rooms"]["now"] == found["rooms"]["before"] > 0.7
        assert found["stays"]["now"] == found["stays"]["before"]
