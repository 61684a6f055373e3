"""Group consistency of loop closures: loops that the sequential chain between them contradicts.

Two loops a->b and c->d whose ends lie close along the path (|a - c| and |b - d| within
`path` m) close a cycle a -> b (loop) -> d (sequential) -> c (loop, inverted) -> a
(sequential); if both are right the cycle is the identity, within the loops' spreads and the
sequential chains' (propagated from the pose graph's sequential edges, first order). A loop is
dropped when more of its neighbours disagree with it than agree (the worst first, counts
updated, until none is left; Olson 2009's pairwise consistency, decided by majority rather
than spectrally, as the groups are small). With `confirm`, a loop that no neighbour agrees
with (a single match) is dropped too: one match in a repetitive place can be wrong in a way
no test on it alone can tell (a corridor whose true pose lies outside the search window), as
ORB-SLAM requires consecutive consistent detections.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from toolkit import se2
from toolkit.slam.graph import Edge
from toolkit.slam.loops import Loop

if TYPE_CHECKING:  # scipy is imported when loops are checked (below): 0.3-0.5 s, and a log
    # without a loop to check never needs it
    from scipy.sparse import csc_matrix

#: chi-square with 3 degrees of freedom, 99%: a cycle this far off is inconsistent
CHI2_3DOF_99 = 11.34


def adjoint(p: np.ndarray) -> np.ndarray:
    """SE(2) adjoint of poses (..., 3) (x, y, theta) in GTSAM's tangent order (x, y, theta):
    (..., 3, 3)."""
    p = np.asarray(p, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    out = np.zeros((*p.shape[:-1], 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = c, -s, p[..., 1]
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = s, c, -p[..., 0]
    out[..., 2, 2] = 1.0
    return out


def _moved(ad: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """ad @ cov @ ad^T over stacks of 3 x 3 matrices."""
    out: np.ndarray = ad @ cov @ np.swapaxes(ad, -1, -2)
    return out


def chain_prefix(keys: np.ndarray, poses: np.ndarray, sequential: Sequence[Edge]) -> np.ndarray:
    """(K, 3, 3): the sequential edges' covariances moved to the world frame and summed up to
    each keyframe; the spread of the chain from keyframe i to j is the difference, moved to
    j's frame (`chain_covariance`). All edges at once (a cumulative sum, in the same order as
    one edge after another)."""
    out = np.zeros((len(keys), 3, 3))
    edges = sequential[: len(keys) - 1]
    if edges:
        ad = adjoint(poses[np.array([e.b for e in edges])])
        cov = np.array([e.covariance for e in edges], dtype=np.float64)
        np.cumsum(_moved(ad, cov), axis=0, out=out[1:])
    return out


def chain_covariance(
    prefix: np.ndarray, i: np.ndarray, j: np.ndarray, end: np.ndarray
) -> np.ndarray:
    """Covariance of the sequential relative pose between keyframe numbers i and j (arrays,
    or ints), in the frame of `end` (the poses at j)."""
    diff = prefix[np.maximum(i, j)] - prefix[np.minimum(i, j)]
    return _moved(adjoint(se2.inverse(end)), diff)


def cycle_chi2(
    first: Loop,
    second: Loop,
    poses: np.ndarray,
    index: dict[int, int],
    prefix: np.ndarray,
    loop_cov: np.ndarray,
    second_cov: np.ndarray | None = None,
) -> float:
    """Mahalanobis distance squared of the cycle first.a -> first.b -> second.b -> second.a ->
    first.a from the identity (loops measured, chains from the sequential `poses`); `loop_cov`
    is the first loop's covariance, `second_cov` the second's (default: the same)."""
    second_cov = loop_cov if second_cov is None else second_cov
    ends = np.array([[first.a, first.b, second.a, second.b]])
    return float(
        cycles_chi2(
            ends,
            first.pose[None],
            second.pose[None],
            poses,
            np.vectorize(index.__getitem__, otypes=[np.int64])(ends),
            prefix,
            np.asarray(loop_cov, np.float64)[None],
            np.asarray(second_cov, np.float64)[None],
        )[0]
    )


def cycles_chi2(
    ends: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    poses: np.ndarray,
    key_number: np.ndarray,
    prefix: np.ndarray,
    first_cov: np.ndarray,
    second_cov: np.ndarray,
) -> np.ndarray:
    """`cycle_chi2` of N loop pairs at once: `ends` (N x 4) their scans (first.a, first.b,
    second.a, second.b), `key_number` the same as keyframe numbers, `first`/`second` (N x 3)
    the loops' poses and `first_cov`/`second_cov` (N x 3 x 3) their covariances."""
    pa, pb, qa, qb = (poses[ends[:, m]] for m in range(4))
    s_b = se2.between(pb, qb)
    s_a = se2.between(qa, pa)
    z_j_inv = se2.inverse(second)
    # cycle = Z_i * S_b * Z_j^-1 * S_a; each factor's spread moved to the cycle's end frame
    suffix3 = s_a
    suffix2 = se2.compose(z_j_inv, s_a)
    suffix1 = se2.compose(s_b, suffix2)
    total = se2.compose(first, suffix1)
    err = np.column_stack([total[:, 0], total[:, 1], se2.wrap(total[:, 2])])

    def moved(cov: np.ndarray, suffix: np.ndarray) -> np.ndarray:
        return _moved(adjoint(se2.inverse(suffix)), cov)

    cov = (
        moved(first_cov, suffix1)
        + moved(chain_covariance(prefix, key_number[:, 1], key_number[:, 3], qb), suffix2)
        + moved(_moved(adjoint(second), second_cov), suffix3)
        + chain_covariance(prefix, key_number[:, 2], key_number[:, 0], pa)
    )
    solved = np.linalg.solve(cov, err[:, :, None])[:, :, 0]
    out: np.ndarray = np.einsum("ni,ni->n", err, solved)
    return out


def _by_column(row: np.ndarray, col: np.ndarray, n: int) -> csc_matrix:
    """The directed pairs (row counts col's vote) as an n x n sparse matrix by column: column
    j's rows are the loops whose count j's vote is in."""
    from scipy.sparse import csc_matrix  # noqa: PLC0415

    return csc_matrix((np.ones(len(row), dtype=np.int8), (row, col)), shape=(n, n))


def check(
    loops: Sequence[Loop],
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    sequential: Sequence[Edge],
    loop_cov: np.ndarray,
    path: float = 10.0,
    chi2: float = CHI2_3DOF_99,
    confirm: bool = True,
) -> dict[int, str]:
    """Reasons to drop, by position in `loops` (the loops to check: those that passed the
    fitness test); loops not in the answer are consistent. `loop_cov`: one covariance for
    every loop, or one per loop (a corridor loop's is long along its axis). `poses` is the
    sequential estimate the `sequential` edges were taken from (keyframes `keys`), `along` its
    path length."""
    n = len(loops)
    if n == 0:
        return {}
    # on use: scipy.sparse with its graphs and scipy.spatial cost 0.3-0.5 s to import
    from scipy.sparse import csr_matrix  # noqa: PLC0415
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415
    from scipy.spatial import cKDTree  # noqa: PLC0415

    covs = np.broadcast_to(np.asarray(loop_cov, np.float64), (n, 3, 3))
    prefix = chain_prefix(keys, poses, sequential)
    ends_along = np.array([[along[lp.a], along[lp.b]] for lp in loops])
    # the pairs nearby (both ends within `path`: Chebyshev distance), never an n x n matrix:
    # a million-scan log passes thousands of loops to this check
    pairs = cKDTree(ends_along).query_pairs(path, p=np.inf, output_type="ndarray")
    first, second = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].T
    ok = np.zeros(len(first), dtype=bool)
    if len(first):  # every pair nearby at once
        ab = np.array([[lp.a, lp.b] for lp in loops], dtype=np.int64)
        pose = np.array([lp.pose for lp in loops], dtype=np.float64)
        ends = np.column_stack([ab[first], ab[second]])
        ok = (
            cycles_chi2(
                ends,
                pose[first],
                pose[second],
                poses,
                np.searchsorted(keys, ends),
                prefix,
                covs[first],
                covs[second],
            )
            <= chi2
        )
    # each pair both ways: row counts column's vote; a corridor loop says nothing along its
    # axis: it neither confirms nor contradicts a full loop (one that is metres off along the
    # corridor would agree with it), only the reverse
    corridor = np.array([lp.axis is not None for lp in loops])
    row, col = np.concatenate([first, second]), np.concatenate([second, first])
    both_ok = np.concatenate([ok, ok])
    voice = ~(~corridor[row] & corridor[col])
    agree = _by_column(row[both_ok & voice], col[both_ok & voice], n)
    disagree = _by_column(row[~both_ok & voice], col[~both_ok & voice], n)
    n_ok = np.bincount(agree.indices, minlength=n)
    n_bad = np.bincount(disagree.indices, minlength=n)
    alive = np.ones(n, dtype=bool)
    out: dict[int, str] = {}
    while True:
        margin = np.where(alive, n_bad - n_ok, -1)
        if margin.max() <= 0:
            break
        worst = np.nonzero(margin == margin.max())[0]
        drop = int(worst[np.argmax([loops[int(w)].ambiguity for w in worst])])
        alive[drop] = False
        out[int(drop)] = f"inconsistent: {n_bad[drop]} loops nearby disagree, {n_ok[drop]} agree"
        # the dropped loop's votes no longer count (the counts are over live loops)
        n_ok[agree.indices[agree.indptr[drop] : agree.indptr[drop + 1]]] -= 1
        n_bad[disagree.indices[disagree.indptr[drop] : disagree.indptr[drop + 1]]] -= 1
    if confirm:
        for i in np.nonzero(alive & (n_ok == 0))[0]:
            out[int(i)] = f"unconfirmed: no loop within {path:g} m agrees"
            alive[i] = False
        # a corridor loop is right across its axis only if its corridor is: a group of corridor
        # loops that agree with each other but with no full loop (a place the match pins down)
        # may all sit in the corridor alongside, when the true one lies beyond the window
        if corridor.any():
            live = ok & alive[first] & alive[second]
            links = csr_matrix(
                (np.ones(int(live.sum()), dtype=bool), (first[live], second[live])), shape=(n, n)
            )
            _, group = connected_components(links, directed=False)
            anchored = np.unique(group[alive & ~corridor])
            for i in np.nonzero(alive & corridor & ~np.isin(group, anchored))[0]:
                out[int(i)] = "unanchored: no full loop agrees with its corridor's loops"
    return out


__all__ = ["CHI2_3DOF_99", "adjoint", "check", "cycle_chi2", "cycles_chi2"]
