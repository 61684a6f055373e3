"""SE(2) arithmetic (`toolkit.se2`), the pose stream type, and the numba kernels' private
copies of both held equal to them on random poses."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.align import se2_jit
from toolkit.dataset import PoseStream, pose_frame
from toolkit.poses import _compose_refs, compose_steps
from toolkit.sim import LaserModel

pose = st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3.1, 3.1))


def random_poses(n: int, seed: int, spread: float = 20.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-spread, spread, (n, 2)), rng.uniform(-4 * np.pi, 4 * np.pi, n)]
    )


@settings(max_examples=60, deadline=None)
@given(pose, pose)
def test_compose_inverse_between(a: tuple[float, ...], b: tuple[float, ...]) -> None:
    pa, pb = np.array(a), np.array(b)
    assert np.allclose(se2.compose(pa, se2.between(pa, pb)), pb, atol=1e-9)
    assert np.allclose(se2.compose(pa, se2.inverse(pa)), 0, atol=1e-9)


def test_compose_is_the_matrix_product() -> None:
    a, b = random_poses(200, 1), random_poses(200, 2)

    def matrix(p: np.ndarray) -> np.ndarray:
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        m = np.zeros((*p.shape[:-1], 3, 3))
        m[..., 0, 0], m[..., 0, 1], m[..., 0, 2] = c, -s, p[..., 0]
        m[..., 1, 0], m[..., 1, 1], m[..., 1, 2] = s, c, p[..., 1]
        m[..., 2, 2] = 1.0
        return m

    ab = se2.compose(a, b)
    assert np.allclose(matrix(ab), matrix(a) @ matrix(b), atol=1e-9)
    assert np.all((ab[:, 2] > -np.pi) & (ab[:, 2] <= np.pi))


def test_wrap_is_half_open_at_minus_pi() -> None:
    theta = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi, 0.0, 7.0, -7.0, 2 * np.pi])
    w = se2.wrap(theta)
    assert np.all((w > -np.pi) & (w <= np.pi))
    assert w[0] == w[1] == np.pi  # -pi maps to pi
    assert np.allclose(np.abs(w[2:4]), np.pi, rtol=0, atol=1e-15)  # +-3 pi (rounded): near +-pi
    assert np.allclose(np.cos(w), np.cos(theta)) and np.allclose(np.sin(w), np.sin(theta))
    assert se2.wrap(0.5).shape == ()


def test_mount_conversion_round_trips() -> None:
    laser = LaserModel(mount_x=0.3).geometry()
    steps = np.array([[0.5, 0.1, 0.3], [1.0, -0.2, -0.5]])
    assert np.allclose(se2.robot_motion(se2.laser_motion(steps, laser), laser), steps)
    # a pure turn of the robot moves a laser mounted ahead of the centre sideways
    turn = se2.laser_motion(np.array([[0.0, 0.0, 0.5]]), laser)[0]
    assert abs(turn[1]) > 0.05 and abs(turn[2] - 0.5) < 1e-12
    # the laser's world pose: 0.3 m ahead along the robot's heading
    robot = np.array([[1.0, 2.0, np.pi / 2]])
    assert np.allclose(se2.laser_poses(robot, laser), [[1.0, 2.3, np.pi / 2]])
    assert np.array_equal(se2.mount_pose(laser), [0.3, 0.0, 0.0])


def test_interpolate_takes_the_short_way_round_and_clamps() -> None:
    t = np.array([1.0, 0.0, 2.0])  # unsorted on purpose
    xyt = np.array([[2.0, 0.0, -3.1], [0.0, 0.0, 3.1], [4.0, 2.0, -3.0]])
    p = se2.interpolate(t, xyt, np.array([-1.0, 0.5, 1.5, 3.0]))
    assert np.allclose(p[0], xyt[1]) and np.allclose(p[3], xyt[2])  # clamped at the ends
    assert p[1, 0] == pytest.approx(1.0)
    assert abs(se2.wrap(p[1, 2] - np.pi)) < 1e-9  # through pi, not through 0
    assert p[2, 2] == pytest.approx(-3.05)
    with pytest.raises(ValueError, match="empty"):
        se2.interpolate(np.zeros(0), np.zeros((0, 3)), t)


def test_pose_stream_round_trips_a_frame() -> None:
    xyt = random_poses(30, 3)
    xyt[:, 2] = se2.wrap(xyt[:, 2])
    t = np.arange(30) * 0.1
    stream = PoseStream.from_frame(pose_frame(t, xyt))
    assert len(stream) == 30 and np.array_equal(stream.xyt, xyt) and np.array_equal(stream.t, t)
    assert list(stream.frame().columns) == ["t", "x", "y", "theta"]
    assert np.array_equal(stream.at(t), xyt)  # its own times: the poses themselves
    mid = stream.at(t[:-1] + 0.05)
    assert np.allclose(mid[:, :2], 0.5 * (xyt[:-1, :2] + xyt[1:, :2]))
    half_turn = se2.wrap(xyt[1:, 2] - xyt[:-1, 2]) / 2
    assert np.allclose(se2.wrap(mid[:, 2] - xyt[:-1, 2] - half_turn), 0, atol=1e-9)
    with pytest.raises(ValueError, match="lacks columns"):
        PoseStream.from_frame(pd.DataFrame({"t": [0.0], "x": [0.0]}))
    with pytest.raises(ValueError, match="times"):
        PoseStream(np.zeros(2), np.zeros((3, 3)))


# ---------------------------------------------------------------- the numba copies


def test_numba_wrap_and_compose_equal_se2() -> None:
    a, b = random_poses(500, 4), random_poses(500, 5)
    wrapped = np.array([se2_jit.wrap(x) for x in a[:, 2]])
    # numpy's and libm's sin/cos/atan2 may differ in the last bit
    assert np.abs(se2.wrap(wrapped - se2.wrap(a[:, 2]))).max() < 1e-15
    assert np.all((wrapped > -np.pi) & (wrapped <= np.pi))
    assert se2_jit.wrap(-np.pi) == np.pi == se2.wrap(-np.pi)
    out = np.empty(3)
    for pa, pb, want in zip(a, b, se2.compose(a, b), strict=True):
        se2_jit.compose_into(pa, pb, out)
        assert np.allclose(out, want, rtol=0, atol=1e-9)
        assert abs(se2.wrap(out[2] - want[2])) < 1e-12


def test_numba_composition_of_keyframe_steps_equals_se2() -> None:
    rng = np.random.default_rng(6)
    steps = np.column_stack(
        [rng.uniform(0, 0.5, 300), rng.normal(0, 0.05, 300), rng.normal(0, 0.4, 300)]
    )
    poses = compose_steps(np.array([1.0, 2.0, 3.0]), steps)
    ref = sc.keyframes(poses, 0.6, 0.5)
    rel = se2.between(poses[ref[1:]], poses[1:])
    slow = [poses[0]]
    for k in range(1, len(ref)):
        slow.append(se2.compose(slow[ref[k]], rel[k - 1]))
    assert np.allclose(_compose_refs(poses[0], ref, rel), np.array(slow), rtol=0, atol=1e-9)


def test_numba_keyframe_rule_equals_se2() -> None:
    odo = compose_steps(np.zeros(3), np.random.default_rng(7).normal(0, 0.3, (400, 3)))
    distance, angle = 0.5, 0.4
    want, key = [0], 0
    for k in range(1, len(odo)):
        want.append(key)
        d = se2.between(odo[key], odo[k])
        if np.hypot(*(odo[k, :2] - odo[key, :2])) >= distance or abs(d[2]) >= angle:
            key = k
    assert list(sc.keyframes(odo, distance, angle)) == want
    assert len(set(want)) > 20  # the rule fired, by distance and by turn


def test_results_filled_in_place_equal_numpy_stack() -> None:
    """`compose` / `inverse` fill their (..., 3) result in place (`_stacked`): the bits and
    dtype `np.stack` gave, for one pose, N x 3, broadcast against one pose, and float32."""

    def stacked(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.stack([x, y, t], axis=-1)

    many, other = random_poses(300, 3), random_poses(300, 4)
    cases = [
        (many[0], other[0]),
        (many, other),
        (many[5], other),
        (many.astype(np.float32), other.astype(np.float32)),
    ]
    for a, b in cases:
        got = (se2.compose(a, b), se2.inverse(a), se2.between(a, b))
        original = se2._stacked
        se2._stacked = stacked
        try:
            want = (se2.compose(a, b), se2.inverse(a), se2.between(a, b))
        finally:
            se2._stacked = original
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.shape == w.shape
            assert g.tobytes() == w.tobytes()
