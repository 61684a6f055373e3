"""Fitting and calibration: the per-beam statistics of the training scans, the background,
the descriptor classifier (`toolkit.features.places`), the temperature by leave-one-out, the
surroundings' offsets and the lateral weight by leave-one-span-out.

    model = fit(ranges, laser, training_components(spans), Config(), spans)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any, NamedTuple

import numpy as np

from toolkit.dataset import LaserGeometry
from toolkit.errors import ToolkitError
from toolkit.features.augment import (
    canonical,
    changed,
    closed,
    differs,
    ended,
    glass_across,
    glazable,
    glazed,
    opened,
    started,
    stretched,
    turned_views,
    walled_across,
    width_factor,
)
from toolkit.features.classify import learn_opening_places
from toolkit.features.descriptors import (
    CLAIM_BESIDE,
    context_windows,
    describe,
    features,
    metres_columns,
    mozos_columns,
    path_length,
    rescaled,
)
from toolkit.features.likelihood import (
    background_bins,
    beam_terms,
    beam_weights,
    commonness,
    loglik,
    per_class,
    softmax,
)
from toolkit.features.model import (
    BACKGROUND_BINS,
    LATERAL_CHOICES,
    LITERAL_EPS,
    Background,
    Config,
    FeatureModel,
)
from toolkit.features.places import PlaceClassifier, fit_places
from toolkit.features.regions import Span, training_components, training_indices


def shifted_copies(scans: np.ndarray, shifts: int) -> tuple[np.ndarray, np.ndarray]:
    """Scans shifted by -shifts..+shifts beams, and the mask of beams that hold data
    (shifted-in edge beams hold none: missing, which is not a no-return)."""
    n, b = scans.shape
    copies = np.full((2 * shifts + 1, n, b), np.nan, dtype=np.float64)
    valid = np.zeros((2 * shifts + 1, n, b), dtype=bool)
    for k, s in enumerate(range(-shifts, shifts + 1)):
        lo, hi = max(0, s), min(b, b + s)
        copies[k, :, lo:hi] = scans[:, lo - s : hi - s]
        valid[k, :, lo:hi] = True
    return copies.reshape(-1, b), valid.reshape(-1, b)


def beam_statistics(
    scans: np.ndarray, laser: LaserGeometry, config: Config
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, variance and return probability per beam from training scans (n x B)."""
    scans = np.asarray(scans, dtype=np.float64)
    if not config.no_return:
        # the literal model: a no-return is the number the sensor sends, range_max
        filled = np.where(np.isfinite(scans), scans, laser.range_max)
        if config.shifts:
            filled, valid = shifted_copies(filled, config.shifts)
            w = valid.astype(np.float64)
            filled = np.where(valid, filled, 0.0)
        else:
            w = np.ones_like(filled)
        count = w.sum(axis=0)
        mean = (w * filled).sum(axis=0) / count
        var = (w * (filled - mean) ** 2).sum(axis=0) / count
        var = _floor(var, mean, config) if config.noise_sigma is not None else var + LITERAL_EPS
        return mean, var, np.ones_like(mean)
    if config.shifts:
        scans, valid = shifted_copies(scans, config.shifts)
    else:
        valid = np.ones(scans.shape, dtype=bool)
    ret = valid & np.isfinite(scans)
    n_valid = valid.sum(axis=0)
    n_ret = ret.sum(axis=0)
    # Jeffreys prior: a beam seen 10 times without a return still might return; with strict
    # returns over the real scans (each scan counts once, however many shifted copies)
    copies = 2 * config.shifts + 1 if config.strict_returns else 1
    p_return = (n_ret / copies + 0.5) / (n_valid / copies + 1.0)
    r = np.where(ret, scans, 0.0)
    seen = n_ret > 0
    mean = np.where(seen, r.sum(axis=0) / np.maximum(n_ret, 1), 0.0)
    var = np.where(ret, (r - mean) ** 2, 0.0).sum(axis=0) / np.maximum(n_ret, 1)
    var = _floor(var, mean, config) if config.noise_sigma is not None else var + LITERAL_EPS
    var = np.where(seen, var, np.inf)
    return mean, var, p_return


def _floor(var: np.ndarray, mean: np.ndarray, config: Config) -> np.ndarray:
    sigma = config.noise_sigma or 0.0
    floor = sigma**2 + (config.range_rel_sigma * mean) ** 2
    return np.asarray(np.maximum(var, floor))


def fit_background(ranges: np.ndarray, laser: LaserGeometry, chunk: int = 65536) -> Background:
    """Per-beam return fraction and log-range histogram of a whole log (the "none" class)."""
    lo = np.log(max(laser.range_min, 0.05))
    hi = np.log(laser.range_max * 1.001)
    edges = np.linspace(lo, hi, BACKGROUND_BINS + 1)
    s, b = ranges.shape
    counts = np.zeros((b, BACKGROUND_BINS), dtype=np.float64)
    returns = np.zeros(b, dtype=np.float64)
    offsets = np.arange(b) * BACKGROUND_BINS
    for i in range(0, s, chunk):
        block = ranges[i : i + chunk]
        ok = np.isfinite(block)
        returns += ok.sum(axis=0)
        idx = background_bins(block, edges)
        flat = (idx + offsets)[ok]
        counts += np.bincount(flat, minlength=b * BACKGROUND_BINS).reshape(b, BACKGROUND_BINS)
    # smooth with a little mass everywhere: the world holds ranges this log did not see
    n = counts.sum(axis=1, keepdims=True)
    prob = (counts + 0.5) / (n + 0.5 * BACKGROUND_BINS)
    width_m = np.diff(np.exp(edges))  # density per metre of range
    log_density = np.log(prob) - np.log(width_m)[None, :]
    p_return = (returns + 0.5) / (s + 1.0)
    return Background(p_return, edges, log_density)


def fit(
    ranges: np.ndarray,
    laser: LaserGeometry,
    training: dict[str, np.ndarray] | list[tuple[str, np.ndarray]],
    config: Config | None = None,
    spans: list[Span] | None = None,
    poses: np.ndarray | None = None,
) -> FeatureModel:
    """Learn a model: per feature (or per component: pairs of feature name and scan indices),
    per-beam statistics of its training scans (indices into `ranges`); the background from
    the whole log; the temperature by leave-one-out; the lateral weight, if the config leaves
    it open, by leave-one-span-out. With `spans` (those `training` came from), a feature's
    separate spans become separate components. `poses` (S x 3, at the scan times) measure
    the path for the descriptors' context (without: `STEP_WITHOUT_POSES` per scan)."""
    config = config or Config()
    sparse = config.descriptors and config.context > 0 and _sparse(len(ranges), poses, config)
    opened_copies = config.augment_open
    if sparse:  # no context to pool: the local map instead, and no opened copies (their
        # opening's length along the path is not described without it; the fit report says so)
        # and the HMM's dwell of `sparse_dwell_stages`: a place of one scan is unlikely
        # (and its path's turning counted by `sparse_turn_length`, its turns pooled over
        # `sparse_turn_pool`, its revisits over `sparse_place_pool`; with `sparse_view_ahead`
        # the view ahead described too)
        config = replace(
            config,
            context=0.0,
            local_map=config.sparse_local_map,
            view_ahead=config.view_ahead or config.sparse_view_ahead,
            augment_open=0.0,
            dwell_stages=config.sparse_dwell_stages or config.dwell_stages,
            turn_length=config.turn_length
            if config.sparse_turn_length is None
            else config.sparse_turn_length,
            turn_pool=config.turn_pool
            if config.sparse_turn_pool is None
            else config.sparse_turn_pool,
            place_pool=config.place_pool
            if config.sparse_place_pool is None
            else config.sparse_place_pool,
        )
    if not training:
        raise ToolkitError("no features to learn")
    components = list(training.items()) if isinstance(training, dict) else list(training)
    if spans and isinstance(training, dict):
        merged = training_indices(spans)
        if merged.keys() == training.keys() and all(
            np.array_equal(merged[f], training[f]) for f in merged
        ):
            components = training_components(spans)  # separate spans: separate components
    background = fit_background(ranges, laser) if config.none_class or config.robust > 0 else None
    model = _statistics(ranges, laser, components, config, background)
    # leave-one-out terms: computed once, for the temperature, the surroundings' offsets and
    # every trial of the lateral weight (they do not depend on it)
    needed = config.temperature == "loo" or _has_offset(config)
    held = held_out_terms(model, ranges, components) if needed else {}
    choice: dict[str, Any] = {}
    if config.lateral_weight is None:
        model, choice = choose_lateral(model, ranges, components, held)
    _calibrate(model, ranges, components, held)
    if config.descriptors:
        model.places = _fit_places(ranges, laser, components, config, poses)
        if config.view_ahead and config.view_ahead_near_bins and config.view_ahead_near_enclosed:
            without = replace(config, view_ahead_near_bins=False)  # for the far-seeing turns
            model.places_far = _fit_places(ranges, laser, components, without, poses)
        model.fit_report["descriptor_temperature"] = round(model.places.temperature, 4)
        model.fit_report.update(model.places.report)
    if sparse:
        model.fit_report["context"] = (
            f"off: fewer than {MIN_CONTEXT_SCANS} scans within the context's path on the "
            "median scan (scans far apart)"
            + (f"; the local map over {config.local_map:g} m instead" if config.local_map else "")
            + ("; no opened copies of the taught scans" if opened_copies else "")
            + f"; the labels' dwell of {config.dwell_stages} stages"
        )
    model.spans = [s.to_dict() for s in spans or []]
    model.fit_report.update(choice)
    if None in (config.beside_places, config.narrow_places, config.glass_to):  # which places
        # the rules beside the laser apply to, from the taught scans' geometry (their names
        # are the user's)
        taught = {
            name: np.concatenate([i for n, i in components if n == name]) for name, _ in components
        }
        model.opening_places = learn_opening_places(
            ranges, laser, poses, taught, config.beside_reach, config.narrow_opening
        )
        model.fit_report["opening_places"] = {k: list(v) for k, v in model.opening_places.items()}
    return model


#: the context is used when the median scan's window holds at least this many scans
MIN_CONTEXT_SCANS = 3


def _sparse(n: int, poses: np.ndarray | None, config: Config) -> bool:
    """Whether scans are too far apart along the path for the context: a window of one or
    two scans holds the neighbouring places, not more of this one (the Intel log's scans
    are about 1 m apart; the simulator's 0.1 m)."""
    lo, hi = context_windows(path_length(n, poses), config.context)
    return n > 0 and float(np.median(hi - lo)) < MIN_CONTEXT_SCANS


def _fit_places(
    ranges: np.ndarray,
    laser: LaserGeometry,
    components: list[tuple[str, np.ndarray]],
    config: Config,
    poses: np.ndarray | None = None,
) -> PlaceClassifier:
    """The descriptor classifier from the training scans, each component a span."""
    # every building at one width: the log's widths rescaled, or it stretched
    measured = ranges
    ranges, factor = canonical(ranges, laser, config.canonical_width, config.canonical_how)
    idx = np.concatenate([i for _, i in components])
    y = np.concatenate([[name] * len(i) for name, i in components])
    groups = np.concatenate([[k] * len(i) for k, (_, i) in enumerate(components)])
    columns = config.columns()
    along = path_length(len(ranges), poses)
    ahead = config.ahead(laser)
    x = features(
        ranges, laser, columns, along, config.context, None, config.beside, poses,
        config.local_map, ahead, config.opening, factor, config.reach_metres,
    )  # fmt: skip
    own_width = len(columns) + (len(metres_columns(columns)) if config.reach_metres else 0)
    rest = np.ones(len(ranges), dtype=bool)
    rest[idx] = False
    open_set = config.open_set if config.none_class else "never"
    claim = None
    if open_set != "never" and config.classifier == "trees":  # the claims' wider strip
        # on what is beside the laser: Mozos et al.'s whole-scan shape (the differences,
        # gaps, polygon and ellipse) is the view to the range limit, and where a place is
        # most of the log its claim learnt from that view what sets the taught spots' view
        # apart from the rest of the place (docs/journal/places.md, session 17); nor on the
        # view ahead (`view_ahead`), for the same reason: with it the claims of brief worlds
        # left most of the corridor unclaimed, taught as none (session 29, axis29)
        beside = replace(config, view_ahead=False).columns()
        base = columns[np.isin(columns, beside)]
        shape = np.isin(base, mozos_columns())
        own = base if config.claim_shape or shape.all() else base[~shape]
        wide = rescaled(describe(ranges, laser, CLAIM_BESIDE)[:, own], own, factor)
        claim = (wide[idx], wide[rest])
    # the taught scans' copies with the less open side of the path closed (or opened): what
    # lies across the path from a place is that spot's accident (a hall opens on one side or
    # on both); copies that are the scan again are left out (`augment.changed`).
    # A scan of `across_of` with glass across the path from its opening (a door across from
    # a window) has no closed or opened copy (`closed` takes the glass for the more open
    # side: the window labelled door) but one walled across from its opening, kept however
    # little glass it saw (the door without the window)
    glassy = np.zeros(len(idx), dtype=bool)
    if config.across_of:
        glassy = np.isin(y, config.across_of) & glass_across(ranges[idx], laser)
    plain = ~glassy if glassy.any() else None
    copies = [
        _Copy(config.augment_closed, closed, which=plain),
        _Copy(config.augment_open, opened, which=plain),
        _Copy(config.augment_closed, walled_across, config.across_of, which=glassy, fresh=False),
    ]
    if config.augment_glass > 0:
        glass_of = config.across_of or ("door",)
        copies.append(_Copy(config.augment_glass, glazed, glass_of, glazable(ranges[idx], laser)))
    # and as at the place's end, ahead and behind (a hall's end, a corner's edge), and the
    # closed copies' ends (a two-sided hall's end as a one-sided one's); where the context is
    # on (measured there only: the sparse path stays as session 23 measured it)
    for front in (True, False) if config.context > 0 else ():
        copies.append(_Copy(config.augment_ends, partial(ended, ahead=front), config.ends_of))
        if config.ends_one_sided:
            closed_end = partial(_closed_end, ahead=front)
            copies.append(_Copy(config.augment_ends, closed_end, config.ends_of))
    # and as from the corridor just outside the place, taught as corridor (where taught);
    # not where the context is off: a scan alone, the hall's near part taught as corridor
    # (a random world's run b, seed 6, with the local map: 0.93 -> 0.76; session 23)
    if "corridor" in y and config.context > 0:
        for front in (True, False):
            for start in (partial(started, ahead=front), partial(_closed_start, ahead=front)):
                copies.append(
                    _Copy(config.augment_starts, start, config.starts_of, label="corridor")
                )
    extra = []
    for c in copies if config.classifier == "trees" else ():
        taken = np.isin(y, c.of) if c.of else np.ones(len(idx), dtype=bool)
        if c.which is not None:
            taken &= c.which
        if c.weight <= 0 or not taken.any():  # no taught scan to copy: no whole-log copy
            continue
        copied = c.make(ranges, laser)
        xa = features(
            copied, laser, columns, along, config.context, None, config.beside, poses,
            config.local_map, ahead, config.opening, factor, config.reach_metres,
        )  # fmt: skip
        if c.fresh:
            taken &= changed(ranges[idx], copied[idx], laser)  # not the scan again
        else:
            taken &= differs(ranges[idx], copied[idx])
        labels = y[taken] if c.label is None else np.full(int(taken.sum()), c.label)
        extra.append((xa[idx][taken], labels, np.full(int(taken.sum()), c.weight)))
    # and as seen from the taught poses turned on the spot (a corridor taught driving along
    # it, met turning at a junction, looks like a room: docs/journal/places.md, session 28);
    # where the context is off (the sparse path, scans taken at every turn), measured there
    views_on = config.augment_turned > 0 and config.context <= 0 and config.classifier == "trees"
    if views_on and poses is not None:
        stretch = config.canonical_how == "stretch" and config.canonical_width > 0
        spread = width_factor(measured, laser, config.canonical_width) if stretch else 1.0
        for turn, rows, views in turned_copies(measured, laser, poses, components, config):
            log, turned = ranges.copy(), np.array(poses, dtype=np.float64)
            log[rows] = stretched(views, laser, spread) if stretch else views
            turned[rows, 2] += turn
            xa = features(
                log, laser, columns, along, config.context, None, config.beside, turned,
                config.local_map, ahead, config.opening, factor, config.reach_metres,
            )  # fmt: skip
            taken = np.isin(idx, rows)
            extra.append(
                (xa[idx][taken], y[taken], np.full(int(taken.sum()), config.augment_turned))
            )
    return fit_places(
        x[idx], y, groups, config.descriptor_c, None, x[rest], config.self_training,
        config.priors, forest=config.classifier == "trees", gate=own_width,
        open_set=open_set, claim=claim, leaf_mix=config.leaf_mix,
        extra=tuple(np.concatenate(v) for v in zip(*extra, strict=True)) if extra else None,
        claim_quantile=config.claim_quantile, along=along[rest], stay_edge=config.stay_edge,
        leaf_weight=config.leaf_weight,
    )  # fmt: skip


#: rad: a taught span that turns less than this over its scans is driven straight (with
#: `Config.turned_spans` "straight", only such spans' views are rendered)
TURN_STRAIGHT = 0.5
#: m of path either side of a taught span whose scans also draw its map for the views
TURN_AROUND = 3.0


def turned_copies(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray,
    components: list[tuple[str, np.ndarray]],
    config: Config,
) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """Per heading of `Config.turned_by` (degrees): the turn (rad), the taught scans viewed
    and their views from their poses turned by it (`augment.turned_views`), rendered from
    the scans within `TURN_AROUND` m of path of their span; of the places `turned_of`
    (empty: all), of the spans `turned_spans` ("straight": those turning less than
    `TURN_STRAIGHT` over their scans). Every view is kept, however much of it the span's map
    did not see (leaving such views out gained nothing: docs/journal/places.md, aug28)."""
    along = path_length(len(ranges), poses)
    theta = np.unwrap(np.asarray(poses, dtype=np.float64)[:, 2])
    spans = []
    for name, idx in components:
        if config.turned_of and name not in config.turned_of:
            continue
        if config.turned_spans == "straight" and np.abs(np.diff(theta[idx])).sum() >= TURN_STRAIGHT:
            continue
        near = (along >= along[idx].min() - TURN_AROUND) & (along <= along[idx].max() + TURN_AROUND)
        spans.append((np.flatnonzero(near), idx))
    out = []
    for degrees in config.turned_by:
        turn = float(np.radians(degrees))
        views = [turned_views(ranges, laser, poses, src, idx, turn)[0] for src, idx in spans]
        if spans:
            out.append((turn, np.concatenate([idx for _, idx in spans]), np.concatenate(views)))
    return out


class _Copy(NamedTuple):
    """One kind of copy of the taught scans that the trees also learn (`_fit_places`)."""

    weight: float  # the copies' weight (0: none)
    make: Callable[[np.ndarray, LaserGeometry], np.ndarray]  # the whole log copied
    of: tuple[str, ...] = ()  # the places whose taught scans are copied (empty: all)
    which: np.ndarray | None = None  # ... and of the taught scans, these (None: all)
    label: str | None = None  # the copies' label (None: the place's own)
    fresh: bool = True  # a copy must differ by `augment.changed` (else: in any beam)


def _closed_end(ranges: np.ndarray, laser: LaserGeometry, ahead: bool) -> np.ndarray:
    """The closed copy (`augment.closed`) as at the place's end (`augment.ended`): a hall open
    on both sides, taught, met at the end of one open on one side."""
    return ended(closed(ranges, laser), laser, ahead=ahead)


def _closed_start(ranges: np.ndarray, laser: LaserGeometry, ahead: bool) -> np.ndarray:
    """The closed copy (`augment.closed`) as from the corridor outside the place
    (`augment.started`): the corridor by a hall open on one side."""
    return started(closed(ranges, laser), laser, ahead=ahead)


def _statistics(
    ranges: np.ndarray,
    laser: LaserGeometry,
    components: list[tuple[str, np.ndarray]],
    config: Config,
    background: Background | None,
) -> FeatureModel:
    """Per component, per-beam statistics of its training scans, on a background fitted."""
    stats = [beam_statistics(ranges[idx], laser, config) for _, idx in components]
    return FeatureModel(
        features=[name for name, _ in components],
        mean=np.array([s[0] for s in stats]),
        var=np.array([s[1] for s in stats]),
        p_return=np.array([s[2] for s in stats]),
        n_scans=np.array([len(idx) for _, idx in components]),
        laser=laser,
        config=config,
        background=background,
    )


def _has_offset(config: Config) -> bool:
    return config.none_class and config.none_model == "surroundings" and config.robust > 0


def _calibrate(
    model: FeatureModel,
    ranges: np.ndarray,
    components: list[tuple[str, np.ndarray]],
    held: dict[int, np.ndarray],
) -> None:
    """The temperature and the surroundings' offsets, from the leave-one-out terms `held`."""
    if model.config.temperature == "loo":
        model.temperature, report = fit_temperature(model, ranges, components, held)
        model.fit_report.update(report)
    if _has_offset(model.config):
        model.none_offset = fit_none_offset(model, ranges, components, held)
        model.fit_report["none_offset"] = dict(
            zip(model.features, model.none_offset.round(2).tolist(), strict=True)
        )


def choose_lateral(
    model: FeatureModel,
    ranges: np.ndarray,
    components: list[tuple[str, np.ndarray]],
    held: dict[int, np.ndarray],
) -> tuple[FeatureModel, dict[str, Any]]:
    """The model with the lateral weight among `LATERAL_CHOICES` under which the training
    spans best predict each other: each span of a feature taught by several is held out, the
    model is calibrated without its row, and the held-out scans' mean log-probability of
    their own feature (tempered, per scan) is averaged. Only the training spans are used
    (`held`: their leave-one-out terms). With no feature taught by two spans or more there is
    nothing to hold out: 0 (all beams alike)."""
    names = model.features
    rows = [k for k, name in enumerate(names) if names.count(name) > 1]
    if not rows:
        alike = replace(model, config=replace(model.config, lateral_weight=0.0))
        return alike, {"lateral_note": "lateral weight 0: no feature has two spans to hold out"}
    scores = {}
    for weight in LATERAL_CHOICES:
        logp = []
        for k in rows:
            keep = [j for j in range(len(names)) if j != k]
            rest = replace(
                model,
                features=[names[j] for j in keep],
                mean=model.mean[keep],
                var=model.var[keep],
                p_return=model.p_return[keep],
                n_scans=model.n_scans[keep],
                config=replace(model.config, lateral_weight=weight),
                fit_report={},
            )
            kept = [components[j] for j in keep]
            _calibrate(rest, ranges, kept, {i: held[j] for i, j in enumerate(keep) if j in held})
            idx = components[k][1]
            prob = softmax(per_class(rest, loglik(rest, ranges[idx]) * rest.temperature))
            logp.append(np.log(np.maximum(prob[:, rest.classes.index(names[k])], 1e-12)).mean())
        scores[weight] = float(np.mean(logp))
    best = max(scores, key=lambda w: scores[w])  # the first of equals: the smaller weight
    report = {
        "lateral_method": "leave-one-span-out: mean log-probability of the held-out span's "
        "own feature",
        "lateral_scores": {f"{w:g}": round(v, 4) for w, v in scores.items()},
        "lateral_weight": best,
    }
    return replace(model, config=replace(model.config, lateral_weight=best)), report


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
