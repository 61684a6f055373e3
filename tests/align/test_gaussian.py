"""The paper's Gaussian alignment (Eq. 3-6) and the ICP baselines on clouds with known shifts."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import toolkit.align as align


def cloud(n: int, dim: int, shift: np.ndarray, noise: float, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    prev = rng.uniform(-1.0, 1.0, (n, dim))
    cur = prev + shift + rng.normal(0.0, noise, (n, dim))
    return cur, prev


@pytest.mark.parametrize("dim", [1, 2, 3, 6])
def test_recovers_a_known_shift_in_any_dimension(dim: int) -> None:
    shift = np.linspace(-0.3, 0.4, dim)
    cur, prev = cloud(2000, dim, shift, 0.01, seed=dim)
    r = align.gaussian(cur, prev)
    assert r.shift.shape == (dim,)
    assert np.linalg.norm(r.shift - shift) < 3e-3
    # Eq. 4 with Gaussian weights exp(-|r|^2 / 2V): each round narrows the weighted spread of
    # N(0, s^2) residuals per axis to 1 / (1/s^2 + 1/V), V the last total variance. It is the
    # noise's spread, never the points' own.
    s2, total = 1e-4, dim * 1e-4
    for _ in range(2):
        total = dim / (1 / s2 + 1 / total)
    assert r.variance == pytest.approx(total, rel=0.15)
    assert r.weights.shape == (2000,)


def test_changed_points_lose_weight_by_default_and_gain_it_as_printed() -> None:
    shift = np.array([0.2, -0.1, 0.05])
    cur, prev = cloud(1000, 3, shift, 0.01, seed=1)
    rng = np.random.default_rng(2)
    moved = rng.choice(1000, 200, replace=False)  # 20% of the points moved on their own
    cur[moved] += rng.uniform(0.5, 1.0, (200, 3))
    text = align.gaussian(cur, prev, iterations=3)
    paper = align.gaussian(cur, prev, iterations=3, variant="paper")
    plain_mean = (cur - prev).mean(axis=0)
    assert np.linalg.norm(text.shift - shift) < 5e-3
    assert np.linalg.norm(plain_mean - shift) > 0.1
    assert np.linalg.norm(paper.shift - shift) > np.linalg.norm(text.shift - shift) * 10
    still = np.setdiff1d(np.arange(1000), moved)
    assert text.weights[moved].max() < 0.01 * text.weights[still].min()
    assert paper.weights[moved].mean() > paper.weights[still].mean()
    # Every weight stays at or below the cap 1 / (2 sigma^2) of the step that set it.
    assert text.weights.max() <= 1.0 / (2 * 0.01**2 * 3 / 2) * 1.5


def test_weights_and_max_shift_bound_the_estimate() -> None:
    shift = np.array([0.3, 0.0])
    cur, prev = cloud(500, 2, shift, 0.005, seed=3)
    w = np.ones(500)
    w[:250] = 0.0
    cur[:250] += 5.0  # only prior-zero-weight points moved
    assert np.linalg.norm(align.gaussian(cur, prev, weights=w).shift - shift) < 2e-3
    capped = align.gaussian(cur + 1.0, prev, max_shift=0.5)
    assert np.linalg.norm(capped.shift) <= 0.5 + 1e-12
    # Displacements beyond the motion model are not evidence: a half-moved cloud keeps the rest.
    far = cur.copy()
    far[:100] += 3.0
    r = align.gaussian(far, prev, max_shift=1.0)
    assert np.linalg.norm(r.shift - shift) < 5e-3
    assert (r.weights[:100] == 0).all()


def test_rejects_mismatched_input() -> None:
    with pytest.raises(ValueError, match="K x D"):
        align.gaussian(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="variant"):
        align.gaussian(np.zeros((3, 2)), np.zeros((3, 2)), variant="other")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="weights"):
        align.gaussian(np.zeros((3, 2)), np.zeros((3, 2)), weights=np.ones(2))


def test_nan_points_are_ignored() -> None:
    shift = np.array([0.1, 0.2])
    cur, prev = cloud(300, 2, shift, 0.002, seed=4)
    cur[:30] = np.nan
    r = align.gaussian(cur, prev)
    assert np.isfinite(r.shift).all() and np.linalg.norm(r.shift - shift) < 2e-3
    assert (r.weights[:30] == 0).all()


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
    st.integers(0, 10_000),
    st.sampled_from(["text", "paper"]),
)
def test_noise_free_shift_is_exact_for_both_variants(
    shift: list[float], seed: int, variant: str
) -> None:
    cur, prev = cloud(50, 3, np.array(shift), 0.0, seed)
    r = align.gaussian(cur, prev, variant=variant)  # type: ignore[arg-type]
    assert np.allclose(r.shift, shift, atol=1e-9)


def test_icp_point_to_point_recovers_small_motion_3d_and_2d() -> None:
    shift = np.array([0.05, -0.03, 0.02])
    cur, prev = cloud(2000, 3, shift, 0.0, seed=5)
    r = align.icp(cur, prev, max_distance=0.2)
    assert r.transform.shape == (4, 4)
    assert np.linalg.norm(r.shift - shift) < 1e-3
    r2 = align.icp(cur[:, :2], prev[:, :2], max_distance=0.2)
    assert r2.transform.shape == (3, 3)
    assert np.linalg.norm(r2.shift - shift[:2]) < 5e-3


def test_icp_point_to_line_on_an_ordered_room_outline() -> None:
    # A rectangle's outline in beam order, rotated and shifted: the line variant recovers it.
    s = np.linspace(0, 1, 200, endpoint=False)
    edges = [
        np.column_stack([4 * s, 0 * s]),
        np.column_stack([4 + 0 * s, 3 * s]),
        np.column_stack([4 - 4 * s, 3 + 0 * s]),
        np.column_stack([0 * s, 3 - 3 * s]),
    ]
    cur = np.vstack(edges) - [2.0, 1.5]
    th = np.deg2rad(3.0)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    prev = (cur - [0.08, -0.05]) @ R  # cur = R prev + t
    r = align.icp(cur, prev, method="point_to_line", max_distance=0.5)
    moved = prev @ r.transform[:2, :2].T + r.transform[:2, 2]
    assert np.abs(moved - cur).max() < 1e-6
    with pytest.raises(ValueError, match="2D"):
        align.icp(np.zeros((5, 3)), np.zeros((5, 3)), method="point_to_line")


def reference_gaussian(
    cur: np.ndarray, prev: np.ndarray, iterations: int, variant: str, max_shift: float | None
) -> tuple[np.ndarray, float, np.ndarray]:
    """Eq. 3-6 written out in plain numpy, the kernels' yardstick."""
    d = cur - prev
    w0 = np.ones(len(d))
    bad = ~np.isfinite(d).all(axis=1)
    w0[bad] = 0.0
    d[bad] = 0.0
    if max_shift is not None:
        w0[(d * d).sum(axis=1) > max_shift**2] = 0.0
    w = w0
    mu = w @ d / w.sum()
    r2 = ((d - mu) ** 2).sum(axis=1)
    var = float(w @ r2 / w.sum())
    for _ in range(iterations):
        cap = 1.0 / (2.0 * max(var, 1e-12))
        w = np.minimum(np.exp(-r2 * cap) * cap * w0 if variant == "text" else w * r2, cap)
        mu = w @ d / w.sum()
        r2 = ((d - mu) ** 2).sum(axis=1)
        var = float(w @ r2 / w.sum())
    if max_shift is not None and np.linalg.norm(mu) > max_shift:
        mu = mu * max_shift / np.linalg.norm(mu)
    return mu, var, w


@pytest.mark.parametrize("variant", ["text", "paper"])
@pytest.mark.parametrize("dim", [2, 3, 5])
def test_kernels_give_the_plain_numpy_numbers(variant: str, dim: int) -> None:
    cur, prev = cloud(3000, dim, np.full(dim, 0.04), 0.01, seed=dim)
    cur[:300] += 0.3  # outliers, some beyond the bound
    cur[7] = np.nan
    for iterations, max_shift in ((2, None), (4, 0.35), (0, None)):
        mu, var, w = reference_gaussian(cur, prev, iterations, variant, max_shift)
        r = align.gaussian(cur, prev, iterations=iterations, max_shift=max_shift, variant=variant)  # type: ignore[arg-type]
        np.testing.assert_allclose(r.shift, mu, rtol=1e-12, atol=1e-15)
        assert r.variance == pytest.approx(var, rel=1e-12)
        np.testing.assert_allclose(r.weights, w, rtol=1e-9, atol=1e-300)
