"""The feature model (paper Eq. 8): one Gaussian per beam and feature, learnt from a few scans.

What the paper leaves open, and is decided here (each switchable, for the ablation):

- no-return beams: a Bernoulli per beam for return / no-return, the Gaussian on returns
  only (`no_return=True`); the paper's literal model treats a no-return as the range_max
  number it is on the wire.
- variance floor: the per-beam variance is at least the sensor's range noise plus a small
  range-proportional term (`noise_sigma`, `range_rel_sigma`); ten scans of a wall otherwise
  give variances near zero and likelihoods that any millimetre kills.
- shifted copies: training scans are also used shifted by +-1..`shifts` beams (a heading
  error of a few beam steps), which widens the Gaussians where a small turn matters.
- the "none" class: a background model of the whole training log (per beam, the fraction of
  returns and a histogram of log-range), the world at large. As a class of its own
  (`none_model="world"`) it is too weak: a feature taught in a corridor explains a plain
  stretch of that corridor better than the world does, on every beam the feature shares
  with it. So "none" is the features' surroundings (`none_model="surroundings"`): per
  feature, its own model on the beams where its reading is common in the log, and the world
  on the beams where it is distinctive (the door's opening, the window's missing returns),
  weighted per beam by `commonness`. A scan is then "none" when a feature's distinctive
  beams do not show it, however well its ordinary beams fit.
- robust beams: per beam, a mixture of the feature's Gaussian and the background, weight
  `robust` (a door seen from another spot of the corridor differs in the beams that look far
  ahead; without it one such beam outweighs every beam that fits).
- strict returns (`strict_returns`, with the surroundings in `SURROUNDINGS`): the mixture with the world covers the
  range of a return only; whether a beam returns at all is the feature's Bernoulli, its
  Jeffreys prior over the real training scans (shifted copies are no new observations: p is
  at most 10.5 / 11 after 10 scans), so glass that gives no return is evidence. That prior
  leaves every always-returning beam a little below the background's return rate, which
  pushes loose features towards "none"; the surroundings' per-feature offset
  (`fit_none_offset`: nine in ten held-out training scans must come out as their feature)
  is what keeps a real log's own training scans from falling to "none".
- temperature: B beams are not independent, so the summed log-likelihood is too confident;
  it is scaled by a factor fitted by leave-one-out on the training scans (see classify.py).
- smoothing along the path (Eq. 7): an HMM over places, forward only (streaming: the map so
  far) or forward-backward (offline: a whole log, each scan also judged by the ones after).
- lateral beams (`lateral_weight`): a place is where the robot is, beside it, and the beams
  that look ahead see the next place a metre or more before the robot is in it; weighting
  each beam's term by |sin(bearing)|^k lets the sides decide. Weighted terms are a weighted
  composite likelihood, tempered the same way (the leave-one-out terms carry the weights).
  Whether that holds depends on the places: a door in a corridor is beside the robot, but a
  corridor told from a room is told by its long view ahead. With `lateral_weight=None` (in
  `SURROUNDINGS`) k is chosen among `LATERAL_CHOICES` by leave-one-span-out on the training
  spans themselves (`choose_lateral`): the k under which each span, held out, is best
  predicted by the feature's other spans.
- evidence length: scans a few centimetres apart see nearly the same thing, so the HMM would
  count one view many times; with `evidence_length` each scan's tempered log-likelihood is
  scaled by the distance travelled since the previous scan over this length (one scan's
  worth of evidence per `evidence_length` metres).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.atomic import atomic_file
from toolkit.dataset import LaserGeometry
from toolkit.errors import FormatError, ToolkitError
from toolkit.features.descriptors import describe, place_columns
from toolkit.features.places import C_DEFAULT, PlaceClassifier, fit_places
from toolkit.features.regions import Span

MODEL_VERSION = 1
LITERAL_EPS = 1e-6  # m^2: the literal model's guard against a zero variance
BACKGROUND_BINS = 128


@dataclass(frozen=True)
class Config:
    """How a model is learnt and applied. `Config()` is the toolkit's method; `PAPER` the
    paper's literal per-scan model."""

    no_return: bool = True
    noise_sigma: float | None = 0.02  # m; None: no variance floor
    range_rel_sigma: float = 0.01  # floor grows with range: sigma^2 += (rel * mean)^2
    shifts: int = 1  # train on copies shifted by +-1..shifts beams
    none_class: bool = True
    robust: float = 0.9  # per beam, the share of readings the world explains, not the feature
    strict_returns: bool = False  # return / no-return not mixed with the world (see above)
    none_model: str = "world"  # "surroundings": the features' surroundings (see above)
    temperature: str = "loo"  # "loo": fitted by leave-one-out; "none": 1 (literal)
    smoothing: str = "forward-backward"  # Eq. 7 offline; "forward": causal (streaming); "none"
    place_length: float = 1.0  # m travelled per expected change of place (HMM switching)
    evidence_length: float | None = 0.5  # m: in the HMM, one scan's evidence per this distance
    lateral_weight: float | None = 0.0  # beams weighted by |sin(bearing)|^this (0: all
    # alike; None: chosen among LATERAL_CHOICES by leave-one-span-out when learning)
    switch_per_scan: float = 0.02  # switching probability per scan when there are no poses
    descriptors: bool = True  # the place classifier on scan descriptors (places.py); False:
    # the per-beam model alone (the paper's, and the options above)
    descriptor_c: float = C_DEFAULT  # inverse L2 strength of the descriptors' regression
    view_ahead: bool = False  # also the descriptors of the view ahead (the next place)
    priors: bool = False  # the places' shares of the training log in the regression
    self_training: int = 3  # rounds of self-training on the rest of the training log
    beam_term: float = 1.0  # weight of the per-beam model's log-posterior added to the
    # descriptors' (0: not used)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Config:
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


PAPER = Config(
    descriptors=False,
    no_return=False,
    noise_sigma=None,
    shifts=0,
    none_class=False,
    robust=0.0,
    strict_returns=False,
    temperature="none",
    smoothing="none",
    evidence_length=None,
)
# the option that meets the calibration target on the simulator (see the README's ablation)
SURROUNDINGS = Config(
    descriptors=False,
    none_model="surroundings",
    strict_returns=True,
    evidence_length=0.15,
    lateral_weight=None,
)
LATERAL_CHOICES = (0.0, 1.0, 2.0)
SMOOTHINGS = ("none", "forward", "forward-backward")
NONE_MODELS = ("surroundings", "world")


@dataclass
class Background:
    """The world at large, per beam: fraction of returns and a log-range histogram density."""

    p_return: np.ndarray  # (B,)
    edges: np.ndarray  # (K+1,) log-range bin edges
    log_density: np.ndarray  # (B, K) log density per metre of range


@dataclass
class FeatureModel:
    """Per feature and beam: mean and variance of the returns, and the return probability.

    Rows are components: a feature taught by separate spans (two corridors) has one row per
    span, and its likelihood is the mixture of its rows."""

    features: list[str]  # feature name of each row (component); names repeat
    mean: np.ndarray  # (F, B) m; beams never seen returning: 0 and var inf
    var: np.ndarray  # (F, B) m^2 (inf: no Gaussian, a uniform range instead)
    p_return: np.ndarray  # (F, B)
    n_scans: np.ndarray  # (F,) training scans per feature
    laser: LaserGeometry
    config: Config = field(default_factory=Config)
    temperature: float = 1.0
    none_offset: np.ndarray | None = None  # (F,) lowers each row's surroundings ("none")
    background: Background | None = None
    spans: list[dict[str, Any]] = field(default_factory=list)
    fit_report: dict[str, Any] = field(default_factory=dict)
    places: PlaceClassifier | None = None  # the classifier on scan descriptors

    @property
    def names(self) -> list[str]:
        """Feature names, each once, in order of first appearance."""
        return list(dict.fromkeys(self.features))

    @property
    def classes(self) -> list[str]:
        """Class names in the order of the probability columns: features, then "none"."""
        return [*self.names, "none"] if self.config.none_class else self.names

    # ------------------------------------------------------------ persistence

    def to_dict(self) -> dict[str, Any]:
        def arr(a: np.ndarray) -> list[float | None]:
            return [None if not np.isfinite(v) else float(v) for v in a]

        out: dict[str, Any] = {
            "version": MODEL_VERSION,
            "kind": "per-beam Gaussian place features (Aznar, Pujol et al. 2014, Eq. 7-9)",
            "laser": self.laser.to_dict(),
            "config": self.config.to_dict(),
            "temperature": self.temperature,
            "training_spans": self.spans,
            "fit_report": self.fit_report,
            "features": [
                {
                    "name": name,
                    "n_scans": int(self.n_scans[k]),
                    "mean": arr(self.mean[k]),
                    "var": arr(self.var[k]),  # null = no Gaussian (never returned)
                    "p_return": arr(self.p_return[k]),
                    **(
                        {"none_offset": float(self.none_offset[k])}
                        if self.none_offset is not None
                        else {}
                    ),
                }
                for k, name in enumerate(self.features)
            ],
        }
        if self.places is not None:
            out["places"] = self.places.to_dict()
        if self.background is not None:
            out["background"] = {
                "p_return": arr(self.background.p_return),
                "log_range_edges": arr(self.background.edges),
                "log_density": [arr(row) for row in self.background.log_density],
            }
        return out

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        with atomic_file(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), allow_nan=False) + "\n")
        return path

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str | Path = "model.json") -> FeatureModel:
        try:
            if d.get("version") != MODEL_VERSION:
                raise FormatError(
                    f"model version {d.get('version')!r}, this toolkit reads {MODEL_VERSION}",
                    file=source,
                )

            def arr(values: list[float | None], missing: float) -> np.ndarray:
                return np.array([missing if v is None else v for v in values], dtype=np.float64)

            feats = d["features"]
            background = None
            if "background" in d:
                b = d["background"]
                background = Background(
                    arr(b["p_return"], 0.5),
                    arr(b["log_range_edges"], 0.0),
                    np.array([arr(row, -50.0) for row in b["log_density"]]),
                )
            return cls(
                features=[f["name"] for f in feats],
                mean=np.array([arr(f["mean"], 0.0) for f in feats]),
                var=np.array([arr(f["var"], np.inf) for f in feats]),
                p_return=np.array([arr(f["p_return"], 0.5) for f in feats]),
                n_scans=np.array([int(f["n_scans"]) for f in feats]),
                laser=LaserGeometry.from_dict(d["laser"]),
                config=Config.from_dict(d["config"]),
                temperature=float(d["temperature"]),
                none_offset=np.array([float(f["none_offset"]) for f in feats])
                if all("none_offset" in f for f in feats)
                else None,
                background=background,
                spans=list(d.get("training_spans", [])),
                fit_report=dict(d.get("fit_report", {})),
                places=PlaceClassifier.from_dict(d["places"]) if "places" in d else None,
            )
        except (KeyError, TypeError, ValueError) as e:
            raise FormatError(
                f"not a feature model ({type(e).__name__}: {e})", file=source
            ) from None

    @classmethod
    def load(cls, path: str | Path) -> FeatureModel:
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except OSError as e:
            raise ToolkitError(f"cannot read: {e.strerror}", file=path) from None
        except json.JSONDecodeError as e:
            raise FormatError(f"invalid JSON: {e.msg}", file=path, record=e.lineno) from None
        return cls.from_dict(d, path)

    def check_laser(self, laser: LaserGeometry, where: str | Path = "dataset") -> None:
        """A model applies only to scans of the same beam layout."""
        mine = self.laser
        if laser.beams != mine.beams:
            raise ToolkitError(
                f"the model was learnt on {mine.beams} beams, the dataset has {laser.beams}",
                file=where,
            )
        for name in ("angle_min", "angle_increment"):
            a, b = getattr(mine, name), getattr(laser, name)
            if abs(a - b) > 1e-6:
                raise ToolkitError(
                    f"the model's {name} is {np.rad2deg(a):.4f}°, the dataset's "
                    f"{np.rad2deg(b):.4f}°: not the same sensor layout",
                    file=where,
                )


# ---------------------------------------------------------------- training


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
    return np.maximum(var, floor)


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


BIN_STEP = 0.002  # m: ranges are binned by table on this grid (no logarithm per reading)


def bin_table(edges: np.ndarray) -> np.ndarray:
    """Log-range bin of each 2 mm cell from 0 to the last edge."""
    k = len(edges) - 1
    cells = int(np.ceil(np.exp(edges[-1]) / BIN_STEP)) + 1
    centres = (np.arange(cells) + 0.5) * BIN_STEP
    pos = (np.log(centres) - edges[0]) * (k / (edges[-1] - edges[0]))
    return np.clip(pos, 0, k - 1).astype(np.int32)


def background_bins(block: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each range (NaN clamped to bin 0: callers mask no-returns)."""
    table = bin_table(edges)
    cell = np.nan_to_num(np.asarray(block, dtype=np.float64) / BIN_STEP, nan=0.0)
    return table[np.clip(cell, 0, len(table) - 1).astype(np.intp)]


def fit(
    ranges: np.ndarray,
    laser: LaserGeometry,
    training: dict[str, np.ndarray] | list[tuple[str, np.ndarray]],
    config: Config | None = None,
    spans: list[Span] | None = None,
) -> FeatureModel:
    """Learn a model: per feature (or per component: pairs of feature name and scan indices),
    per-beam statistics of its training scans (indices into `ranges`); the background from
    the whole log; the temperature by leave-one-out; the lateral weight, if the config leaves
    it open, by leave-one-span-out. With `spans` (those `training` came from), a feature's
    separate spans become separate components."""
    from toolkit.features.classify import held_out_terms

    config = config or Config()
    if not training:
        raise ToolkitError("no features to learn")
    if config.none_model not in NONE_MODELS:
        raise ToolkitError(f"none model {config.none_model!r}: use one of {', '.join(NONE_MODELS)}")
    if config.smoothing not in SMOOTHINGS:
        raise ToolkitError(f"smoothing {config.smoothing!r}: use one of {', '.join(SMOOTHINGS)}")
    if config.temperature not in ("loo", "none"):
        raise ToolkitError(f"temperature {config.temperature!r}: use loo or none")
    components = list(training.items()) if isinstance(training, dict) else list(training)
    if spans and isinstance(training, dict):
        from toolkit.features.regions import training_components, training_indices

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
        model.places = _fit_places(ranges, laser, components, config)
        model.fit_report["descriptor_temperature"] = round(model.places.temperature, 4)
    model.spans = [s.to_dict() for s in spans or []]
    model.fit_report.update(choice)
    return model


def _fit_places(
    ranges: np.ndarray,
    laser: LaserGeometry,
    components: list[tuple[str, np.ndarray]],
    config: Config,
) -> PlaceClassifier:
    """The descriptor classifier from the training scans, each component a span."""
    idx = np.concatenate([i for _, i in components])
    y = np.concatenate([[name] * len(i) for name, i in components])
    groups = np.concatenate([[k] * len(i) for k, (_, i) in enumerate(components)])
    x = describe(ranges, laser)
    rest = np.ones(len(ranges), dtype=bool)
    rest[idx] = False
    columns = np.arange(x.shape[1]) if config.view_ahead else place_columns()
    return fit_places(
        x[idx], y, groups, config.descriptor_c, columns, x[rest], config.self_training,
        config.priors,
    )  # fmt: skip


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
    from toolkit.features.classify import fit_none_offset, fit_temperature

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
    from toolkit.features.classify import loglik, per_class, softmax

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


def commonness(model: FeatureModel) -> np.ndarray:
    """Per model row and beam (F, B), how ordinary the feature's reading is in the log: the
    world's probability of the feature's reading (its return / no-return and range bin, over
    the feature's own distribution) over that of the world's most common reading; 1 where
    the feature reads what the log mostly reads there, near 0 where it is distinctive."""
    from scipy.special import ndtr

    bg = model.background
    if bg is None:
        raise ValueError("commonness needs the background model")
    edges_m = np.exp(bg.edges)
    world_bins = np.exp(bg.log_density) * np.diff(edges_m)[None, :]  # (B, K) given a return
    q = bg.p_return[:, None]
    world = np.concatenate([1.0 - q, q * world_bins], axis=1)  # (B, 1 + K): no-return first
    gauss = np.isfinite(model.var)
    sd = np.sqrt(np.where(gauss, model.var, 1.0))[:, :, None]
    cdf = ndtr((edges_m[None, None, :] - model.mean[:, :, None]) / sd)
    own = np.diff(cdf, axis=2)
    own /= np.maximum(own.sum(axis=2, keepdims=True), 1e-12)
    own = np.where(gauss[:, :, None], own, 1.0 / own.shape[2])  # never returned: any range
    p = model.p_return[:, :, None]
    feature = np.concatenate([1.0 - p, p * own], axis=2)  # (F, B, 1 + K)
    expected = (feature * world[None]).sum(axis=2)
    return np.clip(expected / world.max(axis=1)[None, :], 0.0, 1.0)


def with_config(model: FeatureModel, **changes: Any) -> FeatureModel:
    """The same statistics under changed application settings (e.g. smoothing)."""
    return replace(model, config=replace(model.config, **changes))
