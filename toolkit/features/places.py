"""The place classifier on scan descriptors: learnt from about ten scans per place.

The default is scikit-learn's extremely randomised trees on the standardised descriptors and
their context along the path (`toolkit.features.descriptors.features`): the mean over the
trees of the leaf's class shares is the probability per taught place. `Forest` keeps the
fitted trees as arrays and applies them in a compiled kernel. The alternative
(`forest=False`, `--classifier logistic`) is a multinomial logistic regression,
L2-regularised with `C`, with a temperature (`calibrate`, fitted by leave-one-span-out on
the training spans).

"None of these", twice. The open set (`log_claims`, `open_set`): per taught place, a
logistic regression against the rest of the training log (on the descriptors of what is
beside the laser: `toolkit.features.fitting`), its threshold set by held-out training
spans, claims the log's scans that look like the place; when the places claim
less than `BACKGROUND_SHARE` of the log (taught spots in an untaught background), the
unclaimed scans the trees are unsure of become the trees' own "none" class. And a scan far
from every taught place in the descriptor space (Mahalanobis distance to the nearest class
centre under a shrunk pooled covariance, Ledoit-Wolf, on the scan's own descriptors) is
"none": a logistic function of that distance, beyond `NONE_DISTANCE` times the farthest
held-out training scan's distance.

Only numbers are kept (the scaler, the trees' nodes or the weights, the centres and the
precision matrix), so a model is plain JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from toolkit.errors import ToolkitError

if TYPE_CHECKING:  # scikit-learn is loaded only when learning
    from sklearn.ensemble import ExtraTreesClassifier
    from sklearn.linear_model import LogisticRegression

C_DEFAULT = 0.03  # inverse L2 strength of the logistic regression (tuned on random seeds 0-9)
SELF_TRAINING_ROUNDS = 3
SELF_TRAINING_CONFIDENCE = 0.8
NONE_DISTANCE = 40.0  # "none" beyond this many times the training scans' own distance (seeds 0-9)
NONE_SLOPE = 4.0  # nats per unit of log-distance ratio: how sharp the "none" edge is
TREES = 100  # extremely randomised trees in the forest (100 and 200 alike on seeds 0-19)
LEAF = 4  # training scans at least in a leaf (2-5 alike within 0.01 on seeds 0-19; 4: ECE 0.068 vs 0.082 with 2)
NONE = "\x00none"  # the forest's class of the training log's scans no taught place explains
PROBA_FLOOR = 1e-4  # a forest's probability is at least this (log of 0 is no evidence)
#: share of uniform mixed into every leaf's class shares: a leaf of 4 training scans all of
#: one place does not rule the others out (development seeds 0-19: ECE (a) / (b) / (c)
#: 0.035 / 0.028 / 0.089 -> 0.031 / 0.025 / 0.087, seeds 20-29: 0.047 / 0.042 / 0.068 ->
#: 0.041 / 0.038 / 0.064, balanced accuracy within 0.002; 0.2 cost 0.002-0.004 of (b), (c))
LEAF_MIX = 0.1
#: the resemblance check (`PlaceClassifier.proximity`, `resemblance`): per place, at most
#: this many of the scans the trees were last fitted on under its name are its support (250
#: development worlds: 200 gave the same figures within 0.002, its kernel 2.5x the time)
SUPPORT_SCANS = 50
SUPPORT_NEIGHBOURS = 3  # a scan's proximity to a place: the mean over its closest support scans
#: a scan resembles a place when its proximity is at least this share of the median proximity
#: of the log's scans the trees call that place (development seeds 0-9: 0.5-0.8 alike)
RESEMBLE_MARGIN = 0.7
RESEMBLE_MIN_CALLS = 5  # a place the trees call in fewer of the log's scans is not checked
PROXIMITY_FLOOR = 1e-3  # a scan sharing no leaf with a place's support: this proximity
#: a scan whose checked places all have a probability under this, none of them its call, is
#: not measured: its factor would only lower what is already negligible (no factor instead)
RESEMBLE_SKIP = 1e-3


@dataclass
class Forest:
    """A fitted scikit-learn forest as arrays (every tree's nodes, concatenated): applying it
    needs numpy and numba alone, a saved model stays JSON, and a million scans are scored in
    parallel. `predict_proba` equals scikit-learn's (tested)."""

    roots: np.ndarray  # (T,) node index of each tree's root
    left: np.ndarray  # (N,) child node index; -1 at a leaf
    right: np.ndarray  # (N,)
    feature: np.ndarray  # (N,) column tested at the node
    threshold: np.ndarray  # (N,) go left when the value <= threshold
    value: np.ndarray  # (N, K) class shares at the node

    @classmethod
    def from_sklearn(cls, forest: ExtraTreesClassifier) -> Forest:
        roots, left, right, feature, threshold, value = [], [], [], [], [], []
        offset = 0
        for est in forest.estimators_:
            t = est.tree_
            roots.append(offset)
            leaf = t.children_left < 0
            left.append(np.where(leaf, -1, t.children_left + offset))
            right.append(np.where(leaf, -1, t.children_right + offset))
            feature.append(t.feature)
            threshold.append(t.threshold)
            v = t.value[:, 0, :]
            value.append(v / np.maximum(v.sum(axis=1, keepdims=True), 1e-300))
            offset += t.node_count
        return cls(
            np.array(roots, dtype=np.int64),
            np.concatenate(left).astype(np.int64),
            np.concatenate(right).astype(np.int64),
            np.concatenate(feature).astype(np.int64),
            np.concatenate(threshold).astype(np.float64),
            np.concatenate(value).astype(np.float64),
        )

    def predict_proba(
        self,
        z: np.ndarray,
        columns: np.ndarray | None = None,
        mean: np.ndarray | None = None,
        scale: np.ndarray | None = None,
        leaves: np.ndarray | None = None,
    ) -> np.ndarray:
        """The mean over the trees of the class shares of the leaf each row falls in. With
        `columns`, `mean` and `scale`, `z` holds raw descriptors and the trees (fitted on
        (x[:, columns] - mean) / scale) test x[:, columns[f]] <= threshold * scale + mean:
        the same leaves, without a standardised copy of a million scans' descriptors. With
        `leaves` (S, T int32), the leaf of each row per tree is written there on the way
        (`leaves`), so the resemblance check does not walk the trees again."""
        # leaves step to themselves (threshold +inf), so every tree is walked for its depth's
        # steps without a branch: a node's children side by side, the test picks one; the
        # leaves' shares are divided by the tree count once
        out = np.empty((len(z), self.value.shape[1]))
        _forest_proba(
            np.ascontiguousarray(z, dtype=np.float64),
            *self.walk(columns, mean, scale),
            self.value / len(self.roots),
            out,
            np.empty((0, len(self.roots)), dtype=np.int32) if leaves is None else leaves,
        )
        return out

    def walk(
        self,
        columns: np.ndarray | None = None,
        mean: np.ndarray | None = None,
        scale: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The trees as the compiled walks take them: roots, depths, children side by side
        (leaves step to themselves), the column and the threshold per node; with `columns`,
        `mean` and `scale`, on raw descriptors (the trees fitted on (x[:, columns] - mean) /
        scale, as in `predict_proba`)."""
        leaf = self.left < 0
        f = np.where(leaf, 0, self.feature)
        feature, threshold = f, self.threshold
        if columns is not None and mean is not None and scale is not None:
            feature, threshold = np.asarray(columns)[f], self.threshold * scale[f] + mean[f]
        feature = np.where(leaf, 0, feature).astype(np.int32)
        threshold = np.where(leaf, np.inf, threshold)
        nodes = np.arange(len(leaf))
        children = np.empty((len(leaf), 2), dtype=np.int32)
        children[:, 0] = np.where(leaf, nodes, self.left)
        children[:, 1] = np.where(leaf, nodes, self.right)
        depths = _depths(self.roots, self.left, self.right)
        return self.roots, depths, children.ravel(), feature, threshold

    def leaves(
        self, x: np.ndarray, columns: np.ndarray, mean: np.ndarray, scale: np.ndarray
    ) -> np.ndarray:
        """(S, T int32) the node (index into the concatenated arrays) of the leaf each row of
        raw descriptors `x` falls in, per tree."""
        out = np.empty((len(x), len(self.roots)), dtype=np.int32)
        self.predict_proba(x, columns, mean, scale, out)  # the walk writes the leaves
        return out

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k).tolist() for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Forest:
        ints = ("roots", "left", "right", "feature")
        return cls(
            **{
                k: np.asarray(d[k], dtype=np.int64 if k in ints else np.float64)
                for k in cls.__dataclass_fields__
            }
        )


#: scans walked through one tree together: independent walks overlap their memory waits
TILE = 32


@numba.njit(cache=True)
def _depths(
    roots: np.ndarray, left: np.ndarray, right: np.ndarray
) -> np.ndarray:  # pragma: no cover - numba
    """Per tree, its depth (steps from the root to its deepest leaf)."""
    depth = np.zeros(len(left), dtype=np.int64)
    out = np.zeros(len(roots), dtype=np.int64)
    ends = np.append(roots[1:], len(left))
    for t in range(len(roots)):
        for node in range(roots[t], ends[t]):  # scikit-learn numbers parents before children
            if left[node] >= 0:
                depth[left[node]] = depth[node] + 1
                depth[right[node]] = depth[node] + 1
            out[t] = max(out[t], depth[node])
    return out


@numba.njit(cache=True)
def _tile_columns(z: np.ndarray, a: int, m: int) -> np.ndarray:  # pragma: no cover - numba
    """Rows a .. a + m of `z` copied column by column into a (D, TILE) block."""
    zt = np.empty((z.shape[1], TILE))
    for i in range(m):
        for j in range(z.shape[1]):
            zt[j, i] = z[a + i, j]
    return zt


@numba.njit(cache=True)
def _walk_tile(  # pragma: no cover - numba
    zt: np.ndarray,
    m: int,
    root: int,
    depth: int,
    children: np.ndarray,
    feature: np.ndarray,
    threshold: np.ndarray,
    node: np.ndarray,
) -> None:
    """The tile's `m` scans through one tree step by step together, each step to the child
    at 2 node + (not z <= threshold) (NaN goes right, as in scikit-learn): `node` ends at
    their leaves."""
    for i in range(m):
        node[i] = root
    for _ in range(depth):
        moved = 0
        for i in range(m):
            nd = node[i]
            step = children[2 * nd + np.int64(not zt[feature[nd], i] <= threshold[nd])]
            moved += step != nd  # only a leaf is its own child
            node[i] = step
        if moved == 0:  # the whole tile in leaves before the tree's depth
            break


@numba.njit(parallel=True, cache=True)
def _forest_proba(  # pragma: no cover - numba
    z: np.ndarray,
    roots: np.ndarray,
    depths: np.ndarray,
    children: np.ndarray,
    feature: np.ndarray,
    threshold: np.ndarray,
    share: np.ndarray,
    out: np.ndarray,
    leaves: np.ndarray,
) -> None:
    """Per scan, the sum over the trees (in their order) of its leaf's `share`. Leaves step to
    themselves; a tile of `TILE` scans (its descriptors copied column by column) goes
    through a tree step by step together, each step to the child at 2 node + (not z <=
    threshold) (NaN goes right, as in scikit-learn); `out` is written once. `leaves` with
    a row per scan (not empty): each scan's leaf per tree written there."""
    n, k = z.shape[0], share.shape[1]
    keep = leaves.shape[0] > 0
    for tile in numba.prange((n + TILE - 1) // TILE):
        a = tile * TILE
        m = min(TILE, n - a)
        zt = _tile_columns(z, a, m)
        node = np.empty(TILE, dtype=np.int64)
        acc = np.zeros((TILE, k))
        for t in range(len(roots)):
            _walk_tile(zt, m, roots[t], depths[t], children, feature, threshold, node)
            for i in range(m):
                nd = node[i]
                for c in range(k):
                    acc[i, c] += share[nd, c]
            if keep:
                for i in range(m):
                    leaves[a + i, t] = node[i]
        for i in range(m):
            for c in range(k):
                out[a + i, c] = acc[i, c]


@numba.njit(parallel=True, cache=True)
def _proximity(  # pragma: no cover - numba
    leaves: np.ndarray,
    which: np.ndarray,
    start: np.ndarray,
    rows: np.ndarray,
    place: np.ndarray,
    k: int,
    near: int,
    out: np.ndarray,
) -> None:
    """Per scan `which[i]` (its leaf per tree: a row of `leaves`): how many trees put it in
    one leaf with each support scan (the support scans in leaf n: rows[start[n]:start[n +
    1]]), then per place the mean of its `near` largest counts over the trees (out[i]). Only
    the support scans met are visited, each once."""
    n, trees, r = len(which), leaves.shape[1], len(place)
    for tile in numba.prange((n + TILE - 1) // TILE):
        a = tile * TILE
        m = min(TILE, n - a)
        count = np.zeros(r, dtype=np.int64)
        met = np.empty(r, dtype=np.int64)
        top = np.empty((k, near), dtype=np.int64)
        for i in range(m):
            s = which[a + i]
            n_met = 0
            for t in range(trees):
                nd = leaves[s, t]
                for j in range(start[nd], start[nd + 1]):
                    row = rows[j]
                    if count[row] == 0:
                        met[n_met] = row
                        n_met += 1
                    count[row] += 1
            top[:] = 0
            for q in range(n_met):
                row = met[q]
                c, p = count[row], place[row]
                count[row] = 0  # ready for the next scan
                if c > top[p, near - 1]:  # keep the place's `near` largest, descending
                    w = near - 1
                    while w > 0 and top[p, w - 1] < c:
                        top[p, w] = top[p, w - 1]
                        w -= 1
                    top[p, w] = c
            for p in range(k):
                out[a + i, p] = top[p].sum() / (near * trees)


@numba.njit(parallel=True, cache=True)
def _log_distance(  # pragma: no cover - numba
    x: np.ndarray,
    columns: np.ndarray,
    mean: np.ndarray,
    scale: np.ndarray,
    precision: np.ndarray,
    centres: np.ndarray,
    cpc: np.ndarray,
    out: np.ndarray,
) -> None:
    """Per scan: z = standardised descriptors, min over centres c of z'Pz - 2 z'Pc + c'Pc;
    a tile of `TILE` scans at once, the scans side by side (the inner loops run over them)."""
    n, g, k = x.shape[0], len(columns), len(centres)
    for tile in numba.prange((n + TILE - 1) // TILE):
        a = tile * TILE
        m = min(TILE, n - a)
        z = np.empty((g, TILE))
        zp = np.zeros((g, TILE))
        for s in range(m):
            for i in range(g):
                z[i, s] = (x[a + s, columns[i]] - mean[i]) / scale[i]
        for i in range(g):
            for j in range(g):
                p = precision[i, j]
                for s in range(m):
                    zp[j, s] += z[i, s] * p
        zz = np.zeros(TILE)
        best = np.full(TILE, np.inf)
        for j in range(g):
            for s in range(m):
                zz[s] += zp[j, s] * z[j, s]
        for c in range(k):
            cross = np.zeros(TILE)
            for j in range(g):
                w = centres[c, j]
                for s in range(m):
                    cross[s] += zp[j, s] * w
            for s in range(m):
                best[s] = min(best[s], zz[s] - 2 * cross[s] + cpc[c])
        for s in range(m):
            out[a + s] = 0.5 * np.log(max(best[s], 1e-12))


@dataclass
class PlaceClassifier:
    """Standardiser, logistic regression and the "none" gate, as arrays."""

    classes: list[str]  # taught places, in the order of the coefficient rows
    columns: np.ndarray  # (D,) indices of the descriptors used
    mean: np.ndarray  # (D,)
    scale: np.ndarray  # (D,)
    coef: np.ndarray  # (K, D) on standardised descriptors
    intercept: np.ndarray  # (K,)
    centres: np.ndarray  # (K, D) standardised class means
    precision: np.ndarray  # (D, D) inverse of the shrunk pooled covariance
    reach: float  # the training scans' largest held-out log-distance to their class centre
    temperature: float = 1.0
    forest: Forest | None = None  # the forest, instead of the regression's coef / intercept
    report: dict[str, Any] = field(default_factory=dict)  # how it was learnt (not saved here:
    # the model's fit_report holds it)
    support_leaves: np.ndarray | None = None  # (R, T) the leaf of each support scan per tree
    # (the scans the trees were last fitted on, at most SUPPORT_SCANS a place; None: not kept)
    support_place: np.ndarray | None = None  # (R,) their place (index into `classes`)

    def proximity(self, x: np.ndarray, places: np.ndarray | None = None) -> np.ndarray:
        """(S, K) per scan of raw descriptors and taught place (only `places`, indices, if
        given; the others 0), how much the scan resembles the place's support in the trees'
        own terms: the share of trees that put it in one leaf with a support scan, the mean
        over its `SUPPORT_NEIGHBOURS` closest (1: a scan the trees cannot tell from one
        they learnt the place from). Zeros without a support."""
        if self.forest is None:
            return np.zeros((len(x), len(self.classes)))
        leaves = self.forest.leaves(x, self.columns, self.mean, self.scale)
        return self.proximity_of_leaves(leaves, places)

    def proximity_of_leaves(
        self, leaves: np.ndarray, places: np.ndarray | None = None, which: np.ndarray | None = None
    ) -> np.ndarray:
        """`proximity` of the scans whose leaves per tree are `leaves` (S, T: `Forest.leaves`,
        or those `Forest.predict_proba` wrote on its walk), of its rows `which` (indices,
        default all): the trees are not walked again."""
        k = len(self.classes)
        which = np.arange(len(leaves)) if which is None else np.asarray(which, dtype=np.int64)
        if self.forest is None or self.support_leaves is None or self.support_place is None:
            return np.zeros((len(which), k))
        mine = np.ones(len(self.support_place), dtype=bool)
        if places is not None:
            mine = np.isin(self.support_place, places)
        support, place = self.support_leaves[mine], self.support_place[mine]
        flat = support.ravel()
        order = np.argsort(flat, kind="stable")
        start = np.searchsorted(flat[order], np.arange(len(self.forest.left) + 1))
        rows = (order // support.shape[1]).astype(np.int64)
        out = np.empty((len(which), k))
        _proximity(
            leaves, which, start.astype(np.int64), rows, place.astype(np.int64), k,
            SUPPORT_NEIGHBOURS, out,
        )  # fmt: skip
        return out

    def logits(self, x: np.ndarray, leaves: np.ndarray | None = None) -> np.ndarray:
        """Tempered log-odds (S, K) of descriptors (S, D) (a forest: its log-probabilities;
        with `leaves`, see `Forest.predict_proba`)."""
        if self.forest is not None:  # the trees test the raw descriptors: no standardised copy
            proba = self.forest.predict_proba(x, self.columns, self.mean, self.scale, leaves)
            return np.asarray(np.log(np.maximum(proba, PROBA_FLOOR)))
        z = (x[:, self.columns] - self.mean) / self.scale
        return np.asarray((z @ self.coef.T + self.intercept) * self.temperature)

    def log_distance(self, x: np.ndarray) -> np.ndarray:
        """Per scan, half the log squared Mahalanobis distance to the nearest class centre
        (one compiled pass per tile of scans, tested against the numpy form)."""
        g = self.centres.shape[1]  # the gate's (leading) columns
        cpc = np.einsum("kd,kd->k", self.centres @ self.precision, self.centres)
        out = np.empty(len(x))
        _log_distance(
            np.ascontiguousarray(x, dtype=np.float64), self.columns[:g], self.mean[:g],
            self.scale[:g], np.ascontiguousarray(self.precision), self.centres, cpc, out,
        )  # fmt: skip
        return out

    def log_proba(
        self, x: np.ndarray, none: bool = True, leaves: np.ndarray | None = None
    ) -> np.ndarray:
        """Log-probabilities (S, K + 1 with `none`) of descriptors (S, D) (`leaves`: see
        `Forest.predict_proba`)."""
        logits = self.logits(x, leaves)
        k = len(self.classes)
        if not none:
            logits = logits[:, :k]
        logits -= logits.max(axis=1, keepdims=True)
        logp = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
        if not none:
            return np.asarray(logp)
        edge = NONE_SLOPE * (self.log_distance(x) - self.reach - np.log(NONE_DISTANCE))
        log_none = -np.logaddexp(0.0, -edge)  # log sigmoid
        log_known = -np.logaddexp(0.0, edge)
        if logp.shape[1] > k:  # the forest's own "none": either says none
            # p_none + (1 - p_none) g; the known places keep (1 - g) of their shares
            log_rest = np.logaddexp.reduce(logp[:, :k], axis=1)
            log_none = np.logaddexp(logp[:, k], log_rest + log_none)
            return np.concatenate([logp[:, :k] + log_known[:, None], log_none[:, None]], axis=1)
        return np.concatenate([logp + log_known[:, None], log_none[:, None]], axis=1)

    def to_dict(self) -> dict[str, Any]:
        kind = "extremely randomised trees" if self.forest is not None else "logistic regression"
        return {
            "kind": f"{kind} on scan descriptors (Mozos et al. 2005) and their context, "
            "standardised; none: Mahalanobis distance gate",
            "classes": self.classes,
            "columns": self.columns.tolist(),
            "mean": self.mean.tolist(),
            "scale": self.scale.tolist(),
            "coef": self.coef.tolist(),
            "intercept": self.intercept.tolist(),
            "centres": self.centres.tolist(),
            "precision": self.precision.tolist(),
            "reach": self.reach,
            "temperature": self.temperature,
            **({"forest": self.forest.to_dict()} if self.forest is not None else {}),
            **(
                {
                    "support_leaves": self.support_leaves.tolist(),
                    "support_place": self.support_place.tolist(),
                }
                if self.support_leaves is not None and self.support_place is not None
                else {}
            ),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PlaceClassifier:
        return cls(
            classes=[str(c) for c in d["classes"]],
            columns=np.asarray(d["columns"], dtype=np.int64),
            mean=np.asarray(d["mean"], dtype=np.float64),
            scale=np.asarray(d["scale"], dtype=np.float64),
            coef=np.asarray(d["coef"], dtype=np.float64),
            intercept=np.asarray(d["intercept"], dtype=np.float64),
            centres=np.asarray(d["centres"], dtype=np.float64),
            precision=np.asarray(d["precision"], dtype=np.float64),
            reach=float(d["reach"]),
            temperature=float(d["temperature"]),
            forest=Forest.from_dict(d["forest"]) if "forest" in d else None,
            support_leaves=np.asarray(d["support_leaves"], dtype=np.int64)
            if "support_leaves" in d
            else None,
            support_place=np.asarray(d["support_place"], dtype=np.int64)
            if "support_leaves" in d
            else None,
        )


def fit_places(
    x: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    c: float = C_DEFAULT,
    columns: np.ndarray | None = None,
    unlabelled: np.ndarray | None = None,
    rounds: int = SELF_TRAINING_ROUNDS,
    priors: bool = False,
    forest: bool = True,
    gate: int | None = None,
    open_set: str = "auto",
    claim: tuple[np.ndarray, np.ndarray] | None = None,
    leaf_mix: float = LEAF_MIX,
    extra: tuple[np.ndarray, ...] | None = None,
    claim_quantile: float | None = None,
    along: np.ndarray | None = None,
    stay_edge: float = 0.0,
    leaf_weight: float = 0.0,
    apart: dict[str, str] | None = None,
) -> PlaceClassifier:
    """Learn from descriptors `x` (n, D) of training scans, their places `y` (n,) and their
    spans `groups` (n,: scans of one span share a number), on the descriptors `columns`.
    With `unlabelled` descriptors (the rest of the training log), `rounds` of self-training:
    the scans the classifier labels with probability over `SELF_TRAINING_CONFIDENCE` join
    the training set under their label, each place's together weighing as much as its
    taught scans (ten scans at one spot show one stretch of a corridor; the log shows the
    rest of it). With `priors`, the places' shares of the log, by EM on the unlabelled
    scans' probabilities (`log_priors`), are added to the intercepts: ten scans of each
    place teach it as if every place were as common, while a door is a few scans in a
    hundred of corridor (a regression only). With `forest` (the default), the classifier is
    scikit-learn's extremely randomised trees (`TREES`, leaves of `LEAF` scans or more)
    instead of the regression: ten scans per place are few for a regression's straight
    boundaries between a door, a niche and a side corridor; the trees' averaged leaf shares
    are probabilities that need no temperature (measured on the random worlds). The "none"
    gate measures distances on the first `gate` columns (default all): a scan's own
    descriptors, not their context (ten scans' context is too narrow a cloud to measure
    "far" by). `open_set` ("auto", "always", "never"; trees only): whether the unclaimed
    scans of the log (`log_claims`, on the gate's columns) become a "none" class of the
    trees and stay out of the self-training ("auto": when the places claim less than
    `BACKGROUND_SHARE` of the log). `claim`: the descriptors the claims are tested on, of
    the training scans and of the rest of the log (default: the gate's columns of `x` and
    `unlabelled`); `claim_quantile`: see `log_claims`. `leaf_mix`: the share of uniform
    mixed into every leaf's class shares (trees only; folded into the saved shares, so
    applying the model costs nothing more).
    `extra`: descriptors (m, D), places (m,) and weights (m,) of more training examples for
    the trees only (the taught scans' copies of `toolkit.features.augment`): not in the
    scaler, the claims, the class centres or the gate.
    `along` (the path length of each `unlabelled` scan, in log order) and `stay_edge` (m):
    a self-trained scan must lie more than `stay_edge` of path inside its stay (the run of
    scans the trees give its place), so the ends of a stay, where the place's edge is the
    trees' guess, and stays shorter than twice that teach nothing (`stay_cores`; the rest
    of the log in log order, so a taught span between two scans does not end a stay).
    `leaf_weight`: in the fits on the self-trained log, a leaf holds at least this weight,
    in taught scans (a self-trained scan weighs its place's taught count over its picks: a
    corridor's 600 weigh 0.02 each), so four light self-trained scans of one place are no
    leaf of their own that votes as much as four taught scans (0: `LEAF` scans alone)."""
    columns = np.arange(x.shape[1]) if columns is None else np.asarray(columns)
    x = x[:, columns]
    # scikit-learn is loaded only when learning: applying a saved model needs numpy alone
    from sklearn.covariance import LedoitWolf  # noqa: PLC0415
    from sklearn.ensemble import ExtraTreesClassifier  # noqa: PLC0415
    from sklearn.linear_model import LogisticRegression  # noqa: PLC0415
    from sklearn.preprocessing import StandardScaler  # noqa: PLC0415

    y = np.asarray(y).astype(str)
    classes = list(dict.fromkeys(y))
    if len(classes) < 2:
        raise ToolkitError("the descriptor model needs at least two places to tell apart")
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 1e-9, scaler.scale_, 1.0)
    z = (x - scaler.mean_) / scale

    def learner(weight: float = 0.0) -> ExtraTreesClassifier | LogisticRegression:
        """The classifier; `weight`: the training rows' total weight (for `leaf_weight`)."""
        if forest:
            share = min(0.5, leaf_weight / weight) if leaf_weight > 0 and weight > 0 else 0.0
            return ExtraTreesClassifier(
                TREES, min_samples_leaf=LEAF, min_weight_fraction_leaf=share, random_state=0
            )
        return LogisticRegression(C=c, max_iter=2000)

    za, ya, wa = np.zeros((0, z.shape[1])), np.zeros(0, dtype=str), np.zeros(0)
    apart = apart or {}

    def merged(p: np.ndarray, names: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shares `p` over the trees' classes `names`, each `apart` class's added to its
        place's; and the classes left."""
        if not apart:
            return p, names
        own = ~np.isin(names, list(apart))
        out, left = p[:, own].copy(), list(names[own])
        for j in np.flatnonzero(~own):
            out[:, left.index(apart[str(names[j])])] += p[:, j]
        return out, names[own]

    if extra is not None and forest:
        za = (extra[0][:, columns] - scaler.mean_) / scale
        ya, wa = np.asarray(extra[1]).astype(str), np.asarray(extra[2], dtype=np.float64)
    zu = np.zeros((0, z.shape[1]))
    if unlabelled is not None:
        zu = (unlabelled[:, columns] - scaler.mean_) / scale
    g = gate or z.shape[1]
    # the open-set test on the rest of the log: which scans some taught place claims
    claimed = np.ones(len(zu), dtype=bool)
    if len(za):  # the taught scans' copies join the trees' first fit too
        est = learner().fit(np.vstack([z, za]), np.r_[y, ya], np.r_[np.ones(len(y)), wa])
    else:
        est = learner().fit(z, y)
    if forest and open_set != "never" and len(zu):
        cz, cu = claim if claim is not None else (z[:, :g], zu[:, :g])
        claimed, testable = log_claims(cz, y, groups, cu, claim_quantile)
        # a place taught by one span has no new spot to calibrate its claim by (its halves
        # look alike): the scans the trees give it are its own
        prob, names = merged(est.predict_proba(zu), est.classes_)
        top = prob[:, [list(names).index(k) for k in classes]]
        claimed |= ~np.array([k in testable for k in classes])[top.argmax(axis=1)]
    claimed_share = float(claimed.mean()) if len(zu) else 1.0
    if open_set == "auto" and claimed_share >= BACKGROUND_SHARE:
        claimed[:] = True  # the taught places are most of the log: no background to learn
    learn_none = open_set != "never" and not claimed.all()
    learnt_z, learnt_y = np.vstack([z, za]), np.r_[y, ya]  # what the last fit learnt from
    if len(zu):
        for _ in range(max(rounds, int(learn_none))):  # "none" is learnt even without rounds
            prob, names = merged(est.predict_proba(zu), est.classes_)
            label, sure = names[prob.argmax(axis=1)], prob.max(axis=1)
            zs, ys, ws = [z, za], [y, ya], [np.ones(len(y)), wa]
            core = stay_cores(label, along, stay_edge)
            for k in classes if rounds > 0 else ():
                pick = np.flatnonzero(
                    (label == k) & (sure > SELF_TRAINING_CONFIDENCE) & claimed & core
                )
                if len(pick):
                    zs.append(zu[pick])
                    ys.append(label[pick])
                    ws.append(np.full(len(pick), (y == k).sum() / len(pick)))
            rest = np.flatnonzero(~claimed & (sure <= SELF_TRAINING_CONFIDENCE))
            if learn_none and len(rest):  # unclaimed and unsure: examples of "none", together
                zs.append(zu[rest])  # weighing as much as a taught place
                ys.append(np.full(len(rest), NONE))
                ws.append(np.full(len(rest), len(y) / len(classes) / len(rest)))
            learnt_z, learnt_y, w = np.concatenate(zs), np.concatenate(ys), np.concatenate(ws)
            est = learner(float(w.sum())).fit(learnt_z, learnt_y, sample_weight=w)
    names = merged(np.zeros((0, len(est.classes_))), est.classes_)[1]
    order = [list(names).index(k) for k in classes]
    trees = None
    if forest:
        trees = Forest.from_sklearn(est)
        if NONE in names:
            order.append(list(names).index(NONE))
        trees.value = merged(trees.value, est.classes_)[0][:, order]
        trees.value = (1.0 - leaf_mix) * trees.value + leaf_mix / trees.value.shape[1]
        coef, intercept = np.zeros((len(classes), 0)), np.zeros(len(classes))
    else:
        coef, intercept = est.coef_, est.intercept_
        if len(est.classes_) == 2:  # sklearn keeps one row for two classes: the second's odds
            coef = np.vstack([-coef[0] / 2, coef[0] / 2])
            intercept = np.array([-intercept[0] / 2, intercept[0] / 2])
        coef, intercept = coef[order], intercept[order]
    zg = z[:, : gate or z.shape[1]]
    centres = np.array([zg[y == k].mean(axis=0) for k in classes])
    within = zg - centres[[classes.index(k) for k in y]]
    precision = LedoitWolf().fit(within).precision_
    if unlabelled is not None and priors and not forest:
        zu = (unlabelled[:, columns] - scaler.mean_) / scale
        intercept = intercept + log_priors(zu @ coef.T + intercept)
    model = PlaceClassifier(
        classes, columns, scaler.mean_, scale, coef, intercept, centres, precision, reach=0.0,
        forest=trees,
    )  # fmt: skip
    model.reach = _reach(model, zg, y, classes)
    if forest and trees is not None:
        named = np.array([apart.get(k, k) for k in learnt_y]) if apart else learnt_y
        rows, where = support_rows(named, classes)
        model.support_leaves = est.apply(learnt_z[rows]).astype(np.int64) + trees.roots
        model.support_place = where
    if forest and open_set != "never" and len(zu):
        model.report["open_set"] = (
            f"{open_set}: the places claim {claimed_share:.3f} of the rest of the log; "
            + ("'none' learnt from the unclaimed scans" if learn_none else "no 'none' learnt")
        )
    if not forest:  # the forest's shares are not over-confident (measured: docs/places.md)
        model.temperature = calibrate(model, x, y, groups, c)
    return model


def support_rows(y: np.ndarray, classes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Per taught place, at most `SUPPORT_SCANS` of the rows `y` names it (evenly over
    them): the rows and their place (index into `classes`)."""
    keep, place = [], []
    for j, k in enumerate(classes):
        idx = np.flatnonzero(y == k)
        if len(idx) > SUPPORT_SCANS:
            idx = idx[np.linspace(0, len(idx) - 1, SUPPORT_SCANS).round().astype(np.int64)]
        keep.append(idx)
        place.append(np.full(len(idx), j, dtype=np.int64))
    return np.concatenate(keep), np.concatenate(place)


def resemblance(
    logp: np.ndarray, proximity: np.ndarray, checked: np.ndarray, slope: float
) -> np.ndarray:
    """Per scan of a whole log and taught place, a log-likelihood factor (S, K), <= 0: for
    each place in `checked` (indices) the trees call in `RESEMBLE_MIN_CALLS` scans or more
    (argmax of `logp`'s first K columns), `slope` times the log of how far the scan's
    `proximity` falls under `RESEMBLE_MARGIN` times the median proximity of those calls.
    The reference is the log's own (another world's doors are further from the taught
    ones than the taught world's, all of them): a scan the trees call a door but do not
    put beside any door they learnt, as much as the log's doors are, gives its share to
    the places it does resemble."""
    k = proximity.shape[1]
    out = np.zeros_like(proximity)
    called = logp[:, :k].argmax(axis=1)
    for j in checked:
        mine = called == j
        if mine.sum() < RESEMBLE_MIN_CALLS:
            continue
        ref = RESEMBLE_MARGIN * float(np.median(proximity[mine, j]))
        with np.errstate(divide="ignore"):  # ref 0 (the calls' median unlike any): no penalty
            short = np.log(ref / np.maximum(proximity[:, j], PROXIMITY_FLOOR))  # inf: not measured
        out[:, j] = -slope * np.maximum(short, 0.0)
    return out


def stay_cores(label: np.ndarray, along: np.ndarray | None, edge: float) -> np.ndarray:
    """Per scan (in log order), whether it lies more than `edge` of path (`along`, m) from
    the nearest scan of another label: the core of its stay, where the trees' label is not
    their guess at a place's edge. The log's first and last scans are no edge. All True when
    `edge` is 0 or there is no `along`."""
    n = len(label)
    if not edge or along is None or n == 0:
        return np.ones(n, dtype=bool)
    new_stay = label[1:] != label[:-1]
    change = np.flatnonzero(new_stay) + 1  # first scan of each new stay
    run = np.concatenate(([0], np.cumsum(new_stay)))  # each scan's stay
    before = np.r_[-np.inf, along[change - 1]][run]  # the other label's last scan before
    after = np.r_[along[change], np.inf][run]  # and its first scan after
    return np.asarray(np.minimum(along - before, after - along) > edge)


CLAIM_C = 0.01  # inverse L2 strength of each place's regression against the log
#: share of a place's held-out training scans its claim may miss. 0.1 until session 17: a
#: door's two spans sit at the doorway's two edges, and the tenth of their scans that see
#: wall beside set an edge the plain corridor passes (with the claims on what is beside the
#: laser, the corridor scenario's seeds 1, 3 and 4 claimed 0.88, 0.81 and 0.43 of their
#: log: no "none" learnt). 0.2-0.3 keep seeds 0-4 at 0.16-0.24 and the 100 development
#: worlds at 0.59 or more (docs/journal/places.md, session 17)
CLAIM_QUANTILE = 0.25
CLAIM_LOG_SCANS = 5000  # scans of the log the claims' regressions are fitted against
BACKGROUND_SHARE = 0.3  # open set "auto": on when the places claim less of the log (seeds 0-7)


def log_claims(
    z: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    zu: np.ndarray,
    quantile: float | None = None,
) -> tuple[np.ndarray, set[str]]:
    """Per scan of the rest of the log `zu`, whether some taught place claims it: per place,
    a logistic regression tells its training scans from the log (the log holds the place
    too, but mostly everything else: what it learns is what sets the place apart), and its
    threshold is the `quantile` (default `CLAIM_QUANTILE`) of its held-out training spans'
    scores (each span left out in turn). A scan no place's regression scores as high as its
    own held-out spans is unclaimed. Only places taught by two spans or more are tested
    (returned as the second value): one span's halves look alike, and its claim would be
    too narrow."""
    from sklearn.linear_model import LogisticRegression  # noqa: PLC0415

    share = CLAIM_QUANTILE if quantile is None else quantile
    spread = np.vstack([z, zu]).std(axis=0)
    spread = np.where(spread > 1e-9, spread, 1.0)
    z, zu = z / spread, zu / spread
    claimed = np.zeros(len(zu), dtype=bool)
    testable: set[str] = set()
    log = zu[:: max(1, len(zu) // CLAIM_LOG_SCANS)]  # a long log: every n-th scan

    def against_log(pos: np.ndarray) -> LogisticRegression:
        x = np.vstack([pos, log])
        t = np.r_[np.ones(len(pos)), np.zeros(len(log))]
        return LogisticRegression(C=CLAIM_C, class_weight="balanced", max_iter=500).fit(x, t)

    for k in dict.fromkeys(y):
        own = np.flatnonzero(y == k)
        parts = [own[groups[own] == g] for g in np.unique(groups[own])]
        if len(parts) < 2:
            continue
        testable.add(str(k))
        rest = [np.concatenate(parts[:j] + parts[j + 1 :]) for j in range(len(parts))]
        held = [against_log(z[r]).decision_function(z[p]) for r, p in zip(rest, parts, strict=True)]
        edge = float(np.quantile(np.concatenate(held), share))
        claimed |= against_log(z[own]).decision_function(zu) >= edge
    return claimed, testable


def log_priors(logits: np.ndarray, rounds: int = 50) -> np.ndarray:
    """The log of each class's share of the scans whose logits (fitted under equal shares)
    are given, less log(1/K): the EM of Saerens, Latinne and Decaestecker (2002)."""
    k = logits.shape[1]
    a = logits - logits.max(axis=1, keepdims=True)
    p = np.exp(a)
    p /= p.sum(axis=1, keepdims=True)
    prior = np.full(k, 1.0 / k)
    for _ in range(rounds):
        q = p * (prior * k)
        q /= q.sum(axis=1, keepdims=True)
        prior = np.maximum(q.mean(axis=0), 1e-3)
        prior /= prior.sum()
    return np.asarray(np.log(prior * k))


def _reach(model: PlaceClassifier, z: np.ndarray, y: np.ndarray, classes: list[str]) -> float:
    """The largest log-distance of a training scan to its class centre learnt without it."""
    far = 0.0
    for k in classes:
        idx = np.flatnonzero(y == k)
        if len(idx) < 3:
            continue
        for i in idx:
            rest = idx[idx != i]
            d = z[i] - z[rest].mean(axis=0)
            far = max(far, 0.5 * float(np.log(max(d @ model.precision @ d, 1e-12))))
    return far


def calibrate(
    model: PlaceClassifier, x: np.ndarray, y: np.ndarray, groups: np.ndarray, c: float
) -> float:
    """The temperature under which held-out training spans are best predicted: each span is
    left out (a place taught by one span: half of it), the classifier refitted on the rest,
    and the held-out scans' log-probabilities of their place pooled; the factor maximising
    them (between 0.05 and 10: a strongly regularised fit may also be too timid)."""
    # learning only, as in fit_places: applying a saved model needs numpy alone
    from scipy.optimize import minimize_scalar  # noqa: PLC0415
    from sklearn.linear_model import LogisticRegression  # noqa: PLC0415

    held_logits, held_truth = [], []
    for g in np.unique(groups):
        out = groups == g
        k = y[out][0]
        if (y[~out] == k).sum() == 0:  # the place's only span: hold out its second half
            idx = np.flatnonzero(out)
            out = np.zeros_like(out)
            out[idx[len(idx) // 2 :]] = True
        rest = ~out
        if len(np.unique(y[rest])) < len(model.classes):
            continue
        z = (x - model.mean) / model.scale  # x: the used columns already
        lr = LogisticRegression(C=c, max_iter=2000).fit(z[rest], y[rest])
        logits = lr.decision_function(z[out])
        if logits.ndim == 1:
            logits = np.column_stack([-logits / 2, logits / 2])
        held_logits.append(logits)
        held_truth.append(np.searchsorted(lr.classes_, y[out]))
    if not held_logits:
        return 1.0
    logits, truth = np.concatenate(held_logits), np.concatenate(held_truth)

    def loss(t: float) -> float:
        a = logits * t
        a = a - a.max(axis=1, keepdims=True)
        logp = a - np.log(np.exp(a).sum(axis=1, keepdims=True))
        return -float(logp[np.arange(len(truth)), truth].mean())

    best = minimize_scalar(loss, bounds=(0.05, 10.0), method="bounded")
    return float(best.x)
