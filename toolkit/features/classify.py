"""Classification (paper Eq. 7-9): a probability per feature for every scan, and the class with
the highest posterior.

The per-beam Gaussian log-likelihood of S scans under F features is a quadratic in the
ranges, so it is computed as one matrix product per chunk of scans:

    LL[s, f] = sum_b m_sb (a_fb r_sb^2 + b_fb r_sb + c_fb) + d_f
             = [r^2 | r | m] @ W  (S x 3B times 3B x F)

with m the return mask (Bernoulli per beam for return / no-return) and r centred per beam
(smaller terms, less cancellation). The "none" class is the background model of the world
at large. The sum over beams is tempered (beams are not independent, see
`fit_temperature`), normalised into posteriors (Eq. 9), and smoothed along the trajectory by
an HMM over places (Eq. 7's conditioning on the map: the previous scans, and with
forward-backward, the default for a whole log, the following ones too). In the HMM each scan
counts for the path travelled since the previous one over `evidence_length` (scans a few
centimetres apart are not independent views; see `evidence_weights`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import pandas as pd

from toolkit.features.descriptors import describe
from toolkit.features.model import (
    BIN_STEP,
    Config,
    FeatureModel,
    background_bins,
    beam_statistics,
    bin_table,
    commonness,
)

CHUNK = 8192
LOG_2PI = float(np.log(2 * np.pi))


@dataclass
class Labels:
    """Posteriors per scan over the model's classes, and the winning class."""

    classes: list[str]
    prob: np.ndarray  # (S, K) rows sum to 1
    label: np.ndarray  # (S,) str

    @property
    def confidence(self) -> np.ndarray:
        return self.prob.max(axis=1)

    def frame(self, t: np.ndarray) -> pd.DataFrame:
        """labels.parquet: t, p_<class> per class, label."""
        cols: dict[str, Any] = {"t": np.asarray(t, dtype=np.float64)}
        for k, name in enumerate(self.classes):
            cols[f"p_{name}"] = self.prob[:, k]
        cols["label"] = self.label.astype(str)
        return pd.DataFrame(cols)


# ---------------------------------------------------------------- likelihoods


def _weights(model: FeatureModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-beam centre (B,), the stacked quadratic weights (3B, F) and the bias (F,)."""
    cfg = model.config
    mean, var, p = model.mean, model.var, model.p_return
    gauss = np.isfinite(var)
    seen = gauss.sum(axis=0)
    centre = np.where(gauss, mean, 0.0).sum(axis=0) / np.maximum(seen, 1)
    mu = np.where(gauss, mean - centre, 0.0)
    prec = np.where(gauss, 1.0 / np.where(gauss, var, 1.0), 0.0)
    a = -0.5 * prec
    b = mu * prec
    log_norm = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(np.where(gauss, var, 1.0))),
        -np.log(model.laser.range_max),  # never returned in training: any range alike
    )
    c = log_norm - 0.5 * mu * mu * prec
    weight = beam_weights(model)
    if cfg.no_return:
        p = np.clip(p, 1e-9, 1 - 1e-9)
        c = c + np.log(p) - np.log1p(-p)
        bias = (np.log1p(-p) * weight).sum(axis=1)
    else:
        bias = np.zeros(len(model.features))
    w = np.concatenate([a * weight, b * weight, c * weight], axis=1).T  # (3B, F)
    return centre, np.ascontiguousarray(w), bias


def feature_loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Untempered log-likelihood (S, F) of every scan under every feature (Eq. 8)."""
    centre, w, bias = _weights(model)
    s, nb = ranges.shape
    out = np.empty((s, w.shape[1]), dtype=np.float64)
    x = np.empty((min(chunk, s), 3 * nb), dtype=np.float64)
    for i in range(0, s, chunk):
        block = ranges[i : i + chunk]
        n = len(block)
        xr, xm = x[:n, nb : 2 * nb], x[:n, 2 * nb :]
        ok = np.isfinite(block)
        if model.config.no_return:
            np.subtract(block, centre, out=xr, where=ok)
            xr[~ok] = 0.0
            xm[:] = ok
        else:  # the literal model: a no-return is range_max
            np.subtract(np.where(ok, block, model.laser.range_max), centre, out=xr)
            xm[:] = 1.0
        np.multiply(xr, xr, out=x[:n, :nb])
        np.matmul(x[:n], w, out=out[i : i + n])
    out += bias
    return out


def background_loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Log-likelihood (S,) of every scan under the background (the "none" class)."""
    bg = model.background
    if bg is None:
        raise ValueError("model has no background")
    s, nb = ranges.shape
    k = bg.log_density.shape[1]
    table = bg.log_density.reshape(-1)
    offsets = np.arange(nb) * k
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    weight = beam_weights(model)
    ret_w, miss = np.log(q) - np.log1p(-q), (np.log1p(-q) * weight).sum()
    out = np.empty(s, dtype=np.float64)
    for i in range(0, s, chunk):
        block = ranges[i : i + chunk]
        ok = np.isfinite(block)
        dens = table[background_bins(block, bg.edges) + offsets]
        out[i : i + len(block)] = np.where(ok, dens + ret_w, 0.0) @ weight + miss
    return out


_SOFTPLUS_STEP = 1.0 / 64.0
_SOFTPLUS_RANGE = 16.0  # beyond, log1p(e^-x) < 1.2e-7: the larger term alone
_SOFTPLUS = np.log1p(np.exp(-np.arange(0.0, _SOFTPLUS_RANGE + 2 * _SOFTPLUS_STEP, _SOFTPLUS_STEP)))


@numba.njit(inline="always")
def _logaddexp(a: float, b: float) -> float:  # pragma: no cover - numba
    """log(e^a + e^b) with log1p(e^-|a-b|) from a table (error < 1e-5): no exp/log per term."""
    hi = max(a, b)
    x = (hi - min(a, b)) * 64.0
    if x >= _SOFTPLUS_RANGE * 64.0:
        return hi
    i = int(x)
    w = x - i
    return hi + (1.0 - w) * _SOFTPLUS[i] + w * _SOFTPLUS[i + 1]


@numba.njit(parallel=True, cache=True)
def _robust_kernel(  # pragma: no cover - numba
    ranges: np.ndarray,
    mean: np.ndarray,
    prec: np.ndarray,
    hit: np.ndarray,
    miss: np.ndarray,
    bg_table: np.ndarray,
    bg_hit: np.ndarray,
    bg_miss: np.ndarray,
    bin_of: np.ndarray,
    bin_scale: float,
    log_eps: float,
    ret: np.ndarray,
    mix_hit: np.ndarray,
    miss_eps: float,
    common: np.ndarray,
    weight: np.ndarray,
    out: np.ndarray,
    bg_out: np.ndarray,
    none_out: np.ndarray,
) -> None:
    s_count, nb = ranges.shape
    nf = mean.shape[1]
    last = len(bin_of) - 1
    for s in numba.prange(s_count):
        for f in range(nf):
            out[s, f] = 0.0
            none_out[s, f] = 0.0
        bg_sum = 0.0
        for b in range(nb):
            r = ranges[s, b]
            w = weight[b]
            if np.isfinite(r):
                density = bg_table[b, bin_of[min(max(int(r * bin_scale), 0), last)]]
                world = density + bg_hit[b]
                mix = density + mix_hit[b] + log_eps
                for f in range(nf):
                    d = r - mean[b, f]
                    term = _logaddexp(hit[b, f] - 0.5 * d * d * prec[b, f], mix) + ret[b, f]
                    out[s, f] += w * term
                    none_out[s, f] += common[b, f] * (term - world)
            else:
                world = bg_miss[b]
                for f in range(nf):
                    term = _logaddexp(miss[b, f], world + miss_eps)
                    out[s, f] += w * term
                    none_out[s, f] += common[b, f] * (term - world)
            bg_sum += w * world
        bg_out[s] = bg_sum
        for f in range(nf):
            none_out[s, f] += bg_sum


def _robust_params(model: FeatureModel) -> tuple[np.ndarray, ...]:
    """Per (beam, feature): mean, precision, log-density constant of a return, log-probability
    of a no-return, and a log term added to every return. Mixed with the world (weighted by
    1 - robust): the range of a return, and unless returns are strict, the return itself."""
    gauss = np.isfinite(model.var)
    v = np.where(gauss, model.var, 1.0)
    log_keep = np.log1p(-model.config.robust)
    p = np.clip(model.p_return, 1e-9, 1 - 1e-9)
    norm = np.where(gauss, -0.5 * (LOG_2PI + np.log(v)), -np.log(model.laser.range_max))
    if model.config.strict_returns:
        hit, miss, ret = norm + log_keep, np.log1p(-p), np.log(p)
    else:
        hit, miss, ret = np.log(p) + norm + log_keep, np.log1p(-p) + log_keep, np.zeros_like(p)
    mean = np.where(gauss, model.mean, 0.0)
    prec = np.where(gauss, 1.0 / v, 0.0)
    return tuple(np.ascontiguousarray(a.T) for a in (mean, prec, hit, miss, ret))


def robust_loglik(
    model: FeatureModel, ranges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scan: log-likelihood under each feature with robust beams (each beam a mixture of
    the feature's model and, weight `robust`, the world's), (S, F); under the background,
    (S,); and under each feature's surroundings (its own model on its common beams, the
    world's on its distinctive ones, see `commonness`), (S, F)."""
    bg = model.background
    if bg is None:
        raise ValueError("robust beams need the background model")
    mean, prec, hit, miss, ret = _robust_params(model)
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    strict = model.config.strict_returns
    bin_of = bin_table(bg.edges)
    out = np.empty((len(ranges), len(model.features)))
    bg_out = np.empty(len(ranges))
    none_out = np.empty_like(out)
    common = (
        commonness(model) if model.config.none_model == "surroundings" else np.zeros(mean.T.shape)
    )
    weight = beam_weights(model)
    _robust_kernel(
        np.ascontiguousarray(ranges, dtype=np.float32),
        mean,
        prec,
        hit,
        miss,
        np.ascontiguousarray(bg.log_density),
        np.log(q),
        np.log1p(-q),
        bin_of,
        1.0 / BIN_STEP,
        float(np.log(model.config.robust)),
        ret,
        np.zeros_like(q) if strict else np.log(q),
        -np.inf if strict else float(np.log(model.config.robust)),
        np.ascontiguousarray(common.T * weight[:, None]),  # weighted here, not per scan
        weight,
        out,
        bg_out,
        none_out,
    )
    return out, bg_out, none_out


def beam_weights(model: FeatureModel) -> np.ndarray:
    """Per beam, the weight of its term in the summed log-likelihood (B,): 1, or with
    `lateral_weight` k, |sin(bearing)|^k, so that what is beside the robot counts and what
    lies ahead counts less (a place is where the robot is, not what it drives towards)."""
    k = model.config.lateral_weight
    if not k:
        return np.ones(model.laser.beams)
    bearing = model.laser.angles + model.laser.yaw  # in the robot's frame
    return np.abs(np.sin(bearing)) ** k


def loglik(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Untempered log-likelihood (S, C) per model row (component), then "none" if the model
    has it."""
    if model.config.robust > 0 and model.config.no_return:
        ll, bg, around = robust_loglik(model, ranges)
        if not model.config.none_class:
            return ll
        if model.config.none_model == "surroundings":  # an equal mixture of the features'
            if model.none_offset is not None:
                around -= model.none_offset
            bg = log_mean_exp(around, np.zeros(around.shape[1], dtype=np.int64))[:, 0]
        return np.concatenate([ll, bg[:, None]], axis=1)
    ll = feature_loglik(model, ranges, chunk)
    if model.config.none_class:
        ll = np.concatenate([ll, background_loglik(model, ranges, chunk)[:, None]], axis=1)
    return ll


def per_class(model: FeatureModel, scores: np.ndarray) -> np.ndarray:
    """Scores per class from scores per row: a feature's rows (its components) are an equal
    mixture, log-mean-exp; the "none" column passes through."""
    rows = model.features
    if len(set(rows)) == len(rows):
        return scores
    group = np.array([model.names.index(r) for r in rows], dtype=np.int64)
    mixed = log_mean_exp(scores[:, : len(rows)], group)
    if not model.config.none_class:
        return mixed
    return np.concatenate([mixed, scores[:, len(rows) :]], axis=1)


def log_mean_exp(x: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Per row of `x` (S, K), the log of the mean of exp over the columns of each group
    (`group[k]` in 0..G-1): (S, G). A compiled pass, in parallel over rows (scipy's logsumexp
    on a 1M x 10 array takes longer than the likelihoods' own kernel)."""
    return _log_mean_exp(np.ascontiguousarray(x, dtype=np.float64), group, int(group.max()) + 1)


@numba.njit(parallel=True, cache=True)
def _log_mean_exp(
    x: np.ndarray, group: np.ndarray, n_groups: int
) -> np.ndarray:  # pragma: no cover - numba
    s_count, k = x.shape
    count = np.zeros(n_groups)
    for j in range(k):
        count[group[j]] += 1.0
    out = np.empty((s_count, n_groups))
    for s in numba.prange(s_count):
        for g in range(n_groups):
            hi = -np.inf
            for j in range(k):
                if group[j] == g and x[s, j] > hi:
                    hi = x[s, j]
            if not np.isfinite(hi):
                out[s, g] = hi
                continue
            total = 0.0
            for j in range(k):
                if group[j] == g:
                    total += np.exp(x[s, j] - hi)
            out[s, g] = hi + np.log(total / count[g])
    return out


def softmax(scores: np.ndarray) -> np.ndarray:
    z = scores - scores.max(axis=1, keepdims=True)
    np.exp(z, out=z)
    z /= z.sum(axis=1, keepdims=True)
    return z


# ---------------------------------------------------------------- temperature


def beam_terms(
    scans: np.ndarray, mean: np.ndarray, var: np.ndarray, p: np.ndarray, model: FeatureModel
) -> np.ndarray:
    """Per-beam log-likelihood terms (n, B) of scans under one feature's statistics."""
    cfg = model.config
    if cfg.robust > 0 and cfg.no_return and model.background is not None:
        return _robust_beam_terms(scans, mean, var, p, model)
    if not cfg.no_return:
        r = np.where(np.isfinite(scans), scans, model.laser.range_max)
        return -0.5 * (LOG_2PI + np.log(var) + (r - mean) ** 2 / var)
    ok = np.isfinite(scans)
    gauss = np.isfinite(var)
    v = np.where(gauss, var, 1.0)
    dens = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(v) + (np.nan_to_num(scans) - mean) ** 2 / v),
        -np.log(model.laser.range_max),
    )
    p = np.clip(p, 1e-9, 1 - 1e-9)
    return np.where(ok, np.log(p) + dens, np.log1p(-p))


def world_terms(scans: np.ndarray, model: FeatureModel) -> np.ndarray:
    """Per-beam log-likelihood (n, B) of scans under the background."""
    bg = model.background
    assert bg is not None
    q = np.clip(bg.p_return, 1e-9, 1 - 1e-9)
    idx = background_bins(scans, bg.edges)
    dens = np.take_along_axis(bg.log_density, idx.T, axis=1).T
    return np.where(np.isfinite(scans), dens + np.log(q), np.log1p(-q))


def _robust_beam_terms(
    scans: np.ndarray, mean: np.ndarray, var: np.ndarray, p: np.ndarray, model: FeatureModel
) -> np.ndarray:
    """Robust per-beam terms, as a log-ratio against the background (0 = no evidence)."""
    world = world_terms(scans, model)
    gauss = np.isfinite(var)
    v = np.where(gauss, var, 1.0)
    p = np.clip(p, 1e-9, 1 - 1e-9)
    keep = np.log1p(-model.config.robust)
    dens = np.where(
        gauss,
        -0.5 * (LOG_2PI + np.log(v) + (np.nan_to_num(scans) - mean) ** 2 / v),
        -np.log(model.laser.range_max),
    )
    rho = np.log(model.config.robust)
    if model.config.strict_returns:  # the world explains a return's range, not the return
        q = np.clip(model.background.p_return, 1e-9, 1 - 1e-9)  # type: ignore[union-attr]
        ok = np.isfinite(scans)
        density = world - np.log(q)
        ranged = np.logaddexp(dens + keep, density + rho) - density
        return np.where(ok, ranged + np.log(p) - np.log(q), np.log1p(-p) - np.log1p(-q))
    own = np.where(np.isfinite(scans), np.log(p) + dens, np.log1p(-p)) + keep
    return np.logaddexp(own, world + rho) - world


def held_out_terms(
    model: FeatureModel, ranges: np.ndarray, components: list[tuple[str, np.ndarray]]
) -> dict[int, np.ndarray]:
    """Per model row with 3 or more training scans: the per-beam terms (n, B) of each of its
    scans under the row learnt without it (leave-one-out). Unweighted: they do not depend on
    the lateral weight, which `fit_temperature` and `fit_none_offset` apply."""
    held = {}
    for k, (_, idx) in enumerate(components):
        if len(idx) < 3:
            continue
        scans = ranges[idx].astype(np.float64)
        terms = np.empty_like(scans)
        for j in range(len(idx)):
            rest = np.delete(scans, j, axis=0)
            mean, var, p = beam_statistics(rest, model.laser, model.config)
            terms[j] = beam_terms(scans[j : j + 1], mean, var, p, model)[0]
        held[k] = terms
    return held


NONE_QUANTILE = 0.1  # share of held-out training scans allowed to look like the surroundings
NONE_MARGIN = 0.0  # nats (tempered) by which those scans must prefer their feature


def fit_none_offset(
    model: FeatureModel,
    ranges: np.ndarray,
    components: list[tuple[str, np.ndarray]],
    held: dict[int, np.ndarray] | None = None,
) -> np.ndarray:
    """Per model row, how much to lower its surroundings' score so that its own training
    scans, each held out, come out as the feature and not as "none" (all but
    `NONE_QUANTILE` of them). The user taught these scans as the feature: where the feature
    is loose (scans far apart, a cluttered room), its distinctive beams fit it no better
    than the world, and the surroundings would otherwise claim its own examples."""
    if held is None:
        held = held_out_terms(model, ranges, components)
    common = commonness(model)
    weight = beam_weights(model)
    margin = NONE_MARGIN / model.temperature  # in the untempered units of the terms
    offset = np.zeros(len(components))
    for k, terms in held.items():
        own_vs_around = (terms * weight) @ (1.0 - common[k])
        offset[k] = max(0.0, margin - float(np.quantile(own_vs_around, NONE_QUANTILE)))
    return offset


def fit_temperature(
    model: FeatureModel,
    ranges: np.ndarray,
    components: list[tuple[str, np.ndarray]],
    held: dict[int, np.ndarray] | None = None,
) -> tuple[float, dict[str, Any]]:
    """Scale for the summed log-likelihood, for beams that are not independent.

    Each training scan is scored under its feature learnt without it (leave-one-out). For B
    independent beams the variance of the summed log-likelihood would equal the sum of the
    per-beam variances; correlated beams (one wall seen by many) make it larger. Their ratio
    (the design effect) is the effective share of independent beams, and tempering by it
    (a composite-likelihood magnitude adjustment) keeps posteriors from being overconfident.
    """
    if held is None:
        held = held_out_terms(model, ranges, components)
    weighted = [terms * beam_weights(model) for terms in held.values()]
    centred_terms = [terms - terms.mean(axis=0) for terms in weighted]
    if not centred_terms:
        return 1.0, {"temperature_note": "too few training scans for leave-one-out; 1"}
    terms = np.concatenate(centred_terms)
    n = len(terms) - len(centred_terms)  # degrees of freedom after centring per feature
    per_beam = (terms**2).sum(axis=0).sum() / max(n, 1)
    summed = (terms.sum(axis=1) ** 2).sum() / max(n, 1)
    beams = ranges.shape[1]
    tau = float(np.clip(per_beam / summed, 1.0 / beams, 1.0)) if summed > 0 else 1.0
    return tau, {
        "temperature_method": "leave-one-out design effect (sum of per-beam variances / "
        "variance of the sum)",
        "temperature": tau,
        "effective_beams": tau * beams,
        "loo_scans": len(terms),
    }


# ---------------------------------------------------------------- smoothing (Eq. 7)


@numba.njit(cache=True)
def _forward_backward(
    emit: np.ndarray, eps: np.ndarray, backward: bool
) -> np.ndarray:  # pragma: no cover - numba
    s, k = emit.shape
    alpha = np.empty((s, k))
    prev = np.full(k, 1.0 / k)
    for t in range(s):
        total = 0.0
        for j in range(k):
            a = emit[t, j] * ((1.0 - eps[t]) * prev[j] + eps[t] / k)
            alpha[t, j] = a
            total += a
        for j in range(k):
            alpha[t, j] /= total
            prev[j] = alpha[t, j]
    if not backward:
        return alpha
    beta = np.ones(k)
    nxt = np.empty(k)
    for t in range(s - 1, -1, -1):
        if t < s - 1:
            mix = 0.0
            for j in range(k):
                nxt[j] = emit[t + 1, j] * beta[j]
                mix += nxt[j]
            total = 0.0
            for j in range(k):
                beta[j] = (1.0 - eps[t + 1]) * nxt[j] + eps[t + 1] * mix / k
                total += beta[j]
            for j in range(k):
                beta[j] /= total
        total = 0.0
        for j in range(k):
            alpha[t, j] *= beta[j]
            total += alpha[t, j]
        for j in range(k):
            alpha[t, j] /= total
    return alpha


def switch_probability(config: Config, n: int, poses: np.ndarray | None) -> np.ndarray:
    """Per scan, the probability that the place changed since the previous scan: grows with
    the distance travelled (and turned, 1 rad ~ 1 m) along the trajectory."""
    step = path_steps(n, poses)
    if step is None:
        return np.full(n, config.switch_per_scan)
    step[:1] = 0.0
    eps = -np.expm1(-step / config.place_length)
    return np.clip(np.nan_to_num(eps, nan=config.switch_per_scan), 1e-6, 1.0)


def path_steps(n: int, poses: np.ndarray | None) -> np.ndarray | None:
    """Per scan, the distance travelled since the previous scan (m; turning 1 rad ~ 1 m; the
    first scan: inf, all it sees is new)."""
    if poses is None or len(poses) != n:
        return None
    step = np.full(n, np.inf)
    if n > 1:
        d = np.diff(poses[:, :2], axis=0)
        turn = np.abs(np.remainder(np.diff(poses[:, 2]) + np.pi, 2 * np.pi) - np.pi)
        step[1:] = np.hypot(d[:, 0], d[:, 1]) + turn
    return step


def evidence_weights(config: Config, n: int, poses: np.ndarray | None) -> np.ndarray:
    """Per scan, the share of a scan's evidence the HMM gets from it: the path travelled since
    the previous scan over `evidence_length` (at most 1; a robot standing still adds none);
    1 without poses (or where a pose is NaN)."""
    step = path_steps(n, poses)
    if step is None or not config.evidence_length:
        return np.ones(n)
    return np.nan_to_num(np.clip(step / config.evidence_length, 0.0, 1.0), nan=1.0)


def smooth(emit: np.ndarray, eps: np.ndarray, how: str) -> np.ndarray:
    """HMM over places: forward filter (the map so far) or forward-backward."""
    if how == "none":
        return emit
    return _forward_backward(
        np.ascontiguousarray(emit), np.ascontiguousarray(eps), how != "forward"
    )


# ---------------------------------------------------------------- the whole classification


def classify(
    model: FeatureModel, ranges: np.ndarray, poses: np.ndarray | None = None, chunk: int = CHUNK
) -> Labels:
    """Posterior per class for every scan (Eq. 9), smoothed along the trajectory (Eq. 7).

    `poses` (S x 3: x, y, theta at the scan times) sets how fast places may change; without
    it a fixed switching probability per scan is used.
    """
    model.check_laser(_laser_like(model, ranges))
    cfg = model.config
    scores = class_scores(model, ranges, chunk)
    if cfg.smoothing != "none" and cfg.evidence_length:
        scores *= evidence_weights(cfg, len(scores), poses)[:, None]
    prob = softmax(scores)
    if cfg.smoothing != "none":
        prob = smooth(prob, switch_probability(cfg, len(prob), poses), cfg.smoothing)
    classes = np.array(model.classes)
    return Labels(model.classes, prob, classes[prob.argmax(axis=1)])


def class_scores(model: FeatureModel, ranges: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Per scan and class, the log-score the HMM takes as evidence (S, K): the descriptor
    classifier's log-probabilities, plus `beam_term` times the per-beam model's tempered
    log-posterior; without descriptors, the per-beam model's tempered log-likelihood."""
    cfg = model.config
    if model.places is None or not cfg.descriptors:
        return per_class(model, loglik(model, ranges, chunk) * model.temperature)
    out = np.empty((len(ranges), len(model.classes)))
    for i in range(0, len(ranges), 8 * chunk):
        block = ranges[i : i + 8 * chunk]
        scores = model.places.log_proba(describe(block, model.laser), none=cfg.none_class)
        if cfg.beam_term:
            beams = per_class(model, loglik(model, block, chunk) * model.temperature)
            scores = scores + cfg.beam_term * np.log(softmax(beams))
        out[i : i + len(block)] = scores
    return out


def _laser_like(model: FeatureModel, ranges: np.ndarray) -> Any:
    from dataclasses import replace

    return replace(model.laser, beams=int(ranges.shape[1]))
