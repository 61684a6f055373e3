"""The place classifier on scan descriptors: learnt from about ten scans per place.

A multinomial logistic regression (scikit-learn) on standardised descriptors
(`toolkit.features.descriptors`), L2-regularised with `C`, gives a probability per taught
place. Ten scans per class are few for some sixty descriptors: the strong regularisation
keeps the weights small, and the temperature (`calibrate`, fitted by leave-one-span-out on
the training spans) keeps the probabilities honest on scans the model has not seen.

"None of these": a scan far from every taught place in the descriptor space (Mahalanobis
distance to the nearest class centre under a shrunk pooled covariance, Ledoit-Wolf) is
"none". Its probability is a logistic function of that distance, beyond `none_distance`
times the farthest held-out training scan's distance (a place the user never taught, not a
taught place seen from a new spot).

Only numbers are kept (the scaler, the weights, the centres and the precision matrix), so a
model is plain JSON and applying it is two matrix products per chunk of scans.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from toolkit.errors import ToolkitError

C_DEFAULT = 0.03  # inverse L2 strength of the logistic regression (tuned on random seeds 0-9)
SELF_TRAINING_ROUNDS = 3
SELF_TRAINING_CONFIDENCE = 0.8
NONE_DISTANCE = 15.0  # "none" beyond this many times the training scans' own distance
NONE_SLOPE = 4.0  # nats per unit of log-distance ratio: how sharp the "none" edge is


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

    def logits(self, x: np.ndarray) -> np.ndarray:
        """Tempered log-odds (S, K) of descriptors (S, D)."""
        z = (x[:, self.columns] - self.mean) / self.scale
        return np.asarray((z @ self.coef.T + self.intercept) * self.temperature)

    def log_distance(self, x: np.ndarray) -> np.ndarray:
        """Per scan, half the log squared Mahalanobis distance to the nearest class centre."""
        z = (x[:, self.columns] - self.mean) / self.scale
        zp = z @ self.precision
        quad = np.einsum("sd,sd->s", zp, z)[:, None] - 2 * zp @ self.centres.T
        quad += np.einsum("kd,kd->k", self.centres @ self.precision, self.centres)[None, :]
        return np.asarray(0.5 * np.log(np.maximum(quad.min(axis=1), 1e-12)))

    def log_proba(self, x: np.ndarray, none: bool = True) -> np.ndarray:
        """Log-probabilities (S, K + 1 with `none`) of descriptors (S, D)."""
        logits = self.logits(x)
        logits -= logits.max(axis=1, keepdims=True)
        logp = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
        if not none:
            return np.asarray(logp)
        edge = NONE_SLOPE * (self.log_distance(x) - self.reach - np.log(NONE_DISTANCE))
        log_none = -np.logaddexp(0.0, -edge)  # log sigmoid
        log_known = -np.logaddexp(0.0, edge)
        return np.concatenate([logp + log_known[:, None], log_none[:, None]], axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": "logistic regression on scan descriptors (Mozos et al. 2005), "
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
    hundred of corridor."""
    columns = np.arange(x.shape[1]) if columns is None else np.asarray(columns)
    x = x[:, columns]
    # scikit-learn is loaded only when learning: applying a saved model needs numpy alone
    from sklearn.covariance import LedoitWolf  # noqa: PLC0415
    from sklearn.linear_model import LogisticRegression  # noqa: PLC0415
    from sklearn.preprocessing import StandardScaler  # noqa: PLC0415

    y = np.asarray(y).astype(str)
    classes = list(dict.fromkeys(y))
    if len(classes) < 2:
        raise ToolkitError("the descriptor model needs at least two places to tell apart")
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 1e-9, scaler.scale_, 1.0)
    z = (x - scaler.mean_) / scale
    lr = LogisticRegression(C=c, max_iter=2000).fit(z, y)
    if unlabelled is not None and rounds > 0:
        zu = (unlabelled[:, columns] - scaler.mean_) / scale
        for _ in range(rounds):
            prob = lr.predict_proba(zu)
            label, sure = lr.classes_[prob.argmax(axis=1)], prob.max(axis=1)
            zs, ys, ws = [z], [y], [np.ones(len(y))]
            for k in lr.classes_:
                pick = np.flatnonzero((label == k) & (sure > SELF_TRAINING_CONFIDENCE))
                if len(pick):
                    zs.append(zu[pick])
                    ys.append(label[pick])
                    ws.append(np.full(len(pick), (y == k).sum() / len(pick)))
            lr = LogisticRegression(C=c, max_iter=2000).fit(
                np.concatenate(zs), np.concatenate(ys), sample_weight=np.concatenate(ws)
            )
    order = [list(lr.classes_).index(k) for k in classes]
    coef, intercept = lr.coef_, lr.intercept_
    if len(lr.classes_) == 2:  # sklearn keeps one row for two classes: the second's odds
        coef = np.vstack([-coef[0] / 2, coef[0] / 2])
        intercept = np.array([-intercept[0] / 2, intercept[0] / 2])
    coef, intercept = coef[order], intercept[order]
    centres = np.array([z[y == k].mean(axis=0) for k in classes])
    within = z - centres[[classes.index(k) for k in y]]
    precision = LedoitWolf().fit(within).precision_
    if unlabelled is not None and priors:
        zu = (unlabelled[:, columns] - scaler.mean_) / scale
        intercept = intercept + log_priors(zu @ coef.T + intercept)
    model = PlaceClassifier(
        classes, columns, scaler.mean_, scale, coef, intercept, centres, precision, reach=0.0
    )
    model.reach = _reach(model, z, y, classes)
    model.temperature = calibrate(model, x, y, groups, c)
    return model


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
