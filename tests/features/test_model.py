"""The feature model's math: the vectorized log-likelihoods against a per-beam reference, the
decisions the paper leaves open (no-returns, variance floor, shifted copies, temperature),
smoothing along the trajectory, persistence, and the scores."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tests.features.world import LASER, cast, drive
from toolkit.errors import ToolkitError
from toolkit.features import PAPER, Config, FeatureModel, classify, fit, loglik
from toolkit.features.classify import smooth
from toolkit.features.fitting import (
    beam_statistics,
    fit_background,
    fit_temperature,
    shifted_copies,
)
from toolkit.features.likelihood import (
    background_loglik,
    beam_terms,
    beam_weights,
    commonness,
    feature_loglik,
    robust_loglik,
    world_terms,
)
from toolkit.features.metrics import balanced_accuracy, expected_calibration_error
from toolkit.features.model import MODEL_VERSION
from toolkit.features.places import stay_cores


@pytest.fixture(scope="module")
def world() -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    _, poses, label = drive()
    ranges = cast(poses)
    training = {}
    for feature in ("corridor", "room", "hall"):
        idx = np.flatnonzero(label == feature)
        training[feature] = idx[len(idx) // 2 - 5 : len(idx) // 2 + 5]
    return ranges, poses, label, training


def reference_loglik(model: FeatureModel, ranges: np.ndarray) -> np.ndarray:
    """Per feature, the (weighted) sum over beams of each beam's term: the unvectorized
    definition."""
    weight = beam_weights(model)
    cols = [
        beam_terms(ranges.astype(np.float64), model.mean[k], model.var[k], model.p_return[k], model) @ weight
        for k in range(len(model.features))
    ]  # fmt: skip
    return np.column_stack(cols)


@pytest.mark.parametrize(
    "config",
    [
        PAPER,
        dataclasses.replace(PAPER, no_return=True),
        dataclasses.replace(Config(), robust=0.0),
        dataclasses.replace(Config(), robust=0.0, lateral_weight=1.0),
    ],
)
def test_matrix_product_equals_the_per_beam_sum(world, config: Config) -> None:  # type: ignore[no-untyped-def]
    ranges, _, _, training = world
    model = fit(ranges, LASER, training, config)
    fast = feature_loglik(model, ranges, chunk=64)  # several chunks
    ref = reference_loglik(model, ranges)
    scale = np.maximum(1.0, np.abs(ref))
    assert np.max(np.abs(fast - ref) / scale) < 1e-9


@pytest.mark.parametrize(("strict", "lateral"), [(False, 0.0), (True, 0.0), (True, 1.0)])
def test_robust_kernel_equals_the_mixture_per_beam(world, strict: bool, lateral: float) -> None:  # type: ignore[no-untyped-def]
    ranges, _, _, training = world
    config = Config(strict_returns=strict, none_model="surroundings", lateral_weight=lateral)
    model = fit(ranges, LASER, training, config)
    ll, bg, around = robust_loglik(model, ranges)
    weight = beam_weights(model)
    assert (weight == 1.0).all() if not lateral else weight.min() < 0.05 < 0.99 < weight.max()
    bg_terms = world_terms(ranges.astype(np.float64), model) * weight
    assert np.allclose(bg, bg_terms.sum(axis=1), atol=1e-6)
    common = commonness(model)
    for k in range(len(model.features)):
        ratio = (
            beam_terms(
                ranges.astype(np.float64), model.mean[k], model.var[k], model.p_return[k], model
            )
            * weight
        )
        assert np.allclose(ll[:, k], (ratio + bg_terms).sum(axis=1), atol=1e-3)
        # the surroundings: the feature's own terms on common beams, the world's elsewhere
        surroundings = (common[k] * ratio + bg_terms).sum(axis=1)
        assert np.allclose(around[:, k], surroundings, atol=1e-3)


def test_lateral_weights_scale_the_backgrounds_beams(world) -> None:  # type: ignore[no-untyped-def]
    ranges, _, _, training = world
    model = fit(ranges, LASER, training, Config(robust=0.0, lateral_weight=2.0))
    expected = world_terms(ranges.astype(np.float64), model) @ beam_weights(model)
    assert np.allclose(background_loglik(model, ranges, chunk=64), expected, atol=1e-6)


def test_commonness_tells_distinctive_beams_from_ordinary_ones() -> None:
    """A wall at 2 m the whole log shows is ordinary; the same beams seeing 5 m (a doorway the
    log passes once) or no return (glass) where the log has the wall are distinctive."""
    rng = np.random.default_rng(3)
    log = np.full((400, LASER.beams), 2.0) + rng.normal(0, 0.01, (400, LASER.beams))
    log[100:110, 40:60] = 5.0 + rng.normal(0, 0.01, (10, 20))  # a doorway
    log[200:210, 120:140] = np.nan  # a window
    model = fit(
        log.astype(np.float32), LASER, {"door": np.arange(100, 110), "window": np.arange(200, 210)}
    )
    common = commonness(model)
    door, window = common[model.features.index("door")], common[model.features.index("window")]
    # (the edge beams are smeared by the beam-shifted training copies)
    assert door[41:59].max() < 0.1 and window[121:139].max() < 0.1
    assert door[:38].min() > 0.5 and door[62:].min() > 0.5
    assert window[:118].min() > 0.5 and window[142:].min() > 0.5


def test_no_return_is_a_bernoulli_not_a_number() -> None:
    rng = np.random.default_rng(1)
    scans = np.full((10, LASER.beams), 2.0) + rng.normal(0, 0.01, (10, LASER.beams))
    scans[:, :20] = np.nan  # the first 20 beams never return while learning
    mean, var, p = beam_statistics(scans, LASER, Config(shifts=0))
    assert np.all(np.isinf(var[:20])) and np.all(p[:20] < 0.05) and np.all(p[20:] > 0.95)
    assert np.allclose(mean[20:], 2.0, atol=0.02)
    lit_mean, _, _ = beam_statistics(scans, LASER, PAPER)
    assert np.allclose(lit_mean[:20], LASER.range_max)  # the literal model averages the code


def test_variance_floor_and_literal_epsilon() -> None:
    scans = np.full((10, LASER.beams), 3.0)  # a perfectly still wall: sample variance 0
    _, var, _ = beam_statistics(scans, LASER, Config(shifts=0))
    assert np.allclose(var, 0.02**2 + (0.01 * 3.0) ** 2)
    _, lit_var, _ = beam_statistics(scans, LASER, PAPER)
    assert np.allclose(lit_var, 1e-6)


def test_shifted_copies_mark_edges_missing_not_no_return() -> None:
    scans = np.arange(2 * 6, dtype=np.float64).reshape(2, 6)
    copies, valid = shifted_copies(scans, 1)
    assert copies.shape == (6, 6)
    assert not valid[0, -1] and not valid[4, 0] and valid[2].all()
    assert copies[0, 0] == scans[0, 1] and copies[4, 1] == scans[0, 0]
    # shifted-in edge beams hold no data: they do not count as no-returns
    wall = np.full((10, LASER.beams), 2.0)
    _, _, p = beam_statistics(wall, LASER, Config(shifts=3, strict_returns=False))
    assert np.all(p > 0.98)
    # strict returns: the prior is over the 10 real scans, not the 70 copies
    _, _, p = beam_statistics(wall, LASER, Config(shifts=3, strict_returns=True))
    assert np.allclose(p[3:-3], 10.5 / 11) and np.all(p > 0.9)


def test_temperature_is_the_design_effect_of_correlated_beams() -> None:
    rng = np.random.default_rng(2)
    n, b = 40, LASER.beams
    base = np.full((n, b), 3.0)
    independent = base + rng.normal(0, 0.05, (n, b))
    common = base + rng.normal(0, 0.05, (n, 1))  # one offset for all beams: fully correlated
    cfg = Config(
        descriptors=False, shifts=0, robust=0.0, none_class=False, noise_sigma=0.001,
        range_rel_sigma=0.0,
    )  # fmt: skip
    taus = []
    for scans in (independent, common):
        model = fit(scans.astype(np.float32), LASER, {"wall": np.arange(n)}, cfg)
        taus.append(fit_temperature(model, scans, [("wall", np.arange(n))])[0])
    assert taus[0] > 0.7  # independent beams: close to 1
    assert taus[1] < 5.0 / b  # one common offset: about one effective beam


def test_forward_filter_is_causal_and_smoothing_fixes_isolated_errors() -> None:
    rng = np.random.default_rng(3)
    truth = np.repeat([0, 1, 0, 2], 50)
    emit = np.full((len(truth), 3), 0.1)
    emit[np.arange(len(truth)), truth] = 0.8
    flip = rng.random(len(truth)) < 0.15
    emit[flip] = emit[flip][:, ::-1]
    eps = np.full(len(truth), 0.02)
    raw_errors = np.sum(emit.argmax(axis=1) != truth)
    both = smooth(emit, eps, "forward-backward")
    assert np.sum(both.argmax(axis=1) != truth) < raw_errors / 3
    assert np.allclose(both.sum(axis=1), 1.0)
    fwd = smooth(emit, eps, "forward")
    changed = emit.copy()
    changed[120:] = 1.0 / 3
    assert np.allclose(smooth(changed, eps, "forward")[:120], fwd[:120])  # no look-ahead
    assert not np.allclose(smooth(changed, eps, "forward-backward")[:120], both[:120])


def test_dwell_stages_leave_out_short_stays_and_keep_long_ones() -> None:
    """With two states per place a stay of a few scans (a false door) costs more than with
    the geometric dwell, a long one is kept; one stage is the plain HMM; forward is causal."""
    truth = np.repeat([0, 1, 0, 1, 0], [100, 6, 100, 60, 100])
    emit = np.full((len(truth), 2), 0.35)
    emit[np.arange(len(truth)), truth] = 0.65
    eps = np.full(len(truth), 0.02)
    one, two = smooth(emit, eps, "forward-backward"), smooth(emit, eps, "forward-backward", 2)
    assert np.allclose(one, smooth(emit, eps, "forward-backward", 1))
    assert np.allclose(two.sum(axis=1), 1.0)
    short, long = slice(100, 106), slice(206, 266)
    assert two[short, 1].mean() < one[short, 1].mean()
    assert (two[long].argmax(axis=1) == 1).mean() > 0.9
    changed = emit.copy()
    changed[150:] = 0.5
    fwd = smooth(emit, eps, "forward", 2)
    assert np.allclose(smooth(changed, eps, "forward", 2)[:150], fwd[:150])


def test_stay_cores_leave_out_the_ends_of_each_stay() -> None:
    label = np.array(list("aaaaaabbbaaaaaaaa"))
    along = np.arange(len(label)) * 0.1
    # 0.15 m: the scan next to another label's is an end; the log's own ends are not
    core = stay_cores(label, along, 0.15)
    assert core.tolist() == [bool(int(c)) for c in "11111001001111111"]
    # the whole 0.4 m stay of "b" (from the last "a" before to the first after) is an end
    assert not stay_cores(label, along, 0.25)[6:9].any()
    # off: every scan, and without a path every scan too
    assert stay_cores(label, along, 0.0).all() and stay_cores(label, None, 0.3).all()
    # scans unevenly spaced: the distance is along the path, not in scans
    along2 = np.r_[along[:6], along[6:] + 1.0]  # 1.1 m between the last "a" and the "b"
    assert not core[5] and stay_cores(label, along2, 0.15)[5]


def test_standing_still_adds_no_evidence(world) -> None:  # type: ignore[no-untyped-def]
    """With an evidence length, a robot that stops and scans the same spot five times over is
    no surer of its place than one that scanned it once; without it the HMM counts the view
    five times and grows more confident."""
    ranges, poses, _, training = world
    model = fit(ranges, LASER, training, Config(descriptors=False))  # the per-beam model
    assert model.config.evidence_length and model.config.smoothing == "forward-backward"
    once = classify(model, ranges, poses)
    still = np.repeat(np.arange(len(ranges)), 5)
    again = classify(model, ranges[still], poses[still])
    assert np.allclose(again.prob[::5], once.prob, atol=1e-4)
    assert np.array_equal(again.label[::5], once.label)
    counted = dataclasses.replace(
        model, config=dataclasses.replace(model.config, evidence_length=None)
    )
    base, five = classify(counted, ranges, poses), classify(counted, ranges[still], poses[still])
    assert five.confidence[::5].mean() > base.confidence.mean() + 0.01


def test_model_json_round_trip_and_sensor_check(world, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    ranges, poses, _, training = world
    model = fit(ranges, LASER, training)
    path = model.save(tmp_path / "model.json")
    again = FeatureModel.load(path)
    assert again.features == model.features and again.config == model.config
    assert np.allclose(
        classify(again, ranges, poses).prob, classify(model, ranges, poses).prob, atol=1e-9
    )
    with pytest.raises(ToolkitError, match="learnt on 181 beams, the dataset has 180"):
        again.check_laser(dataclasses.replace(LASER, beams=180))
    with pytest.raises(ToolkitError, match="angle_increment"):
        again.check_laser(dataclasses.replace(LASER, angle_increment=LASER.angle_increment / 2))
    (tmp_path / "bad.json").write_text(f'{{"version": {MODEL_VERSION}, "features": 3}}')
    with pytest.raises(ToolkitError, match="not a feature model"):
        FeatureModel.load(tmp_path / "bad.json")
    (tmp_path / "bad.json").write_text('{"version": 1, "features": []}')  # learn anew
    with pytest.raises(ToolkitError, match=f"model version 1, this toolkit reads {MODEL_VERSION}"):
        FeatureModel.load(tmp_path / "bad.json")


def test_a_config_saved_before_its_fields_existed_applies_as_it_did() -> None:
    now = Config().to_dict()
    assert Config.from_dict(now) == Config()
    # session 17 saved canonical_width without canonical_how: its log was stretched
    stretch = {k: v for k, v in now.items() if k != "canonical_how"} | {"canonical_width": 2.0}
    assert Config.from_dict(stretch).canonical_how == "stretch"
    # before session 17, no canonical width at all: the descriptors as measured
    before = {k: v for k, v in now.items() if not k.startswith("canonical_")}
    assert Config.from_dict(before).canonical_width == 0.0
    # before session 20, no resemblance check (a model saved then has no support either)
    unchecked = {k: v for k, v in now.items() if not k.startswith("resemble")}
    assert Config.from_dict(unchecked).resemble == 0.0 and Config().resemble > 0
    assert Config.from_dict(now).resemble_places == ("door", "window")  # JSON: a list
    # before session 23, a sparse log's labels kept the geometric dwell
    geometric = {k: v for k, v in now.items() if k != "sparse_dwell_stages"}
    assert Config.from_dict(geometric).sparse_dwell_stages == 0 < Config().sparse_dwell_stages
    # before session 23, no copies as from the corridor outside a place: learnt without
    unstarted = {k: v for k, v in now.items() if k not in ("augment_starts", "starts_of")}
    assert Config.from_dict(unstarted).augment_starts == 0.0 and Config().augment_starts > 0
    unended = {k: v for k, v in now.items() if k not in ("augment_ends", "ends_of")}
    assert Config.from_dict(unended).augment_ends == 0.0 and Config().augment_ends > 0
    # before session 24, a door's closed copy could wall the door where glass lay across
    unglazed = {k: v for k, v in now.items() if k != "across_of"}
    assert Config.from_dict(unglazed).across_of == () and Config().across_of == ("door",)
    # before session 24 (glass24), a window call kept where a room was seen beside the laser
    roomless = {k: v for k, v in now.items() if k != "glass_to"}
    assert Config.from_dict(roomless).glass_to == () and Config().glass_to is None
    # session 24's saved pair is kept: a model saved then applies as it did
    named = {**now, "glass_to": ["window", "door"]}
    assert Config.from_dict(named).glass_to == ("window", "door")
    # before session 25, a door's zone past its opening stayed corridor
    marginless = {k: v for k, v in now.items() if k != "room_margin"}
    assert Config.from_dict(marginless).room_margin == 0.0 < Config().room_margin
    # before session 27, a sparse log's turns on the spot were not pooled, and the expert's
    # pooled turn took the mean over every turn
    unpooled = {k: v for k, v in now.items() if "turn_pool" not in k}
    old = Config.from_dict(unpooled)
    assert (old.sparse_turn_pool, old.turn_pool_rule, old.turn_pool_reach) == (None, "mean", 0.0)
    assert old.turn_pool_door == 0 < Config().turn_pool_door
    assert Config().sparse_turn_pool == 0.3 and Config().turn_pool == 0.0  # dense: none
    # before session 28, no revisit was pooled (a model then has neither field)
    unvisited = {k: v for k, v in now.items() if "place_pool" not in k}
    old = Config.from_dict(unvisited)
    assert (old.sparse_place_pool, old.place_pool) == (None, 0.0)
    assert Config().sparse_place_pool == 4.0 and Config().place_pool == 0.0  # dense: none
    # before session 28, a junction's long turn beside an enclosed turn was not pooled
    unjunctioned = {k: v for k, v in now.items() if k != "turn_pool_junction"}
    assert Config.from_dict(unjunctioned).turn_pool_junction == 0 < Config().turn_pool_junction
    # before session 29, a sparse log's trees did not take the view ahead
    blinkered = {k: v for k, v in now.items() if k != "sparse_view_ahead"}
    assert not Config.from_dict(blinkered).sparse_view_ahead and Config().sparse_view_ahead
    assert not Config().view_ahead  # dense: the place's columns alone


def test_background_density_integrates_to_one() -> None:
    ranges = cast(drive()[1])
    bg = fit_background(ranges, LASER)
    widths = np.diff(np.exp(bg.edges))
    assert np.allclose((np.exp(bg.log_density) * widths).sum(axis=1), 1.0)


def test_probabilities_and_labels_on_the_ray_cast_world(world) -> None:  # type: ignore[no-untyped-def]
    ranges, poses, label, training = world
    test = np.ones(len(label), dtype=bool)
    test[np.concatenate(list(training.values()))] = False
    scores = {}
    for name, config in (("paper", PAPER), ("toolkit", Config(descriptors=False))):
        model = fit(ranges, LASER, training, config)  # the per-beam models
        out = classify(model, ranges, poses)
        assert out.prob.shape == (len(ranges), len(model.classes))
        assert np.allclose(out.prob.sum(axis=1), 1.0)
        correct = out.label[test] == label[test]
        scores[name] = (
            balanced_accuracy(label[test], out.label[test]),
            expected_calibration_error(out.confidence[test], correct),
        )
        # every training scan is labelled as its own feature
        for feature, idx in training.items():
            assert np.mean(out.label[idx] == feature) >= 0.9, (name, feature)
    assert scores["toolkit"][0] > scores["paper"][0] + 0.2
    assert scores["toolkit"][1] < scores["paper"][1]


def test_balanced_accuracy_and_ece_by_hand() -> None:
    truth = np.array(["a", "a", "a", "a", "b", "none"])
    pred = np.array(["a", "a", "a", "b", "b", "a"])
    assert balanced_accuracy(truth, pred) == pytest.approx((0.75 + 1.0 + 0.0) / 3)
    conf = np.array([0.95, 0.95, 0.55, 0.55])
    correct = np.array([1, 1, 1, 0])
    # bin (0.933, 1]: acc 1 vs conf 0.95; bin (0.533, 0.6]: acc 0.5 vs conf 0.55
    assert expected_calibration_error(conf, correct) == pytest.approx(0.5 * 0.05 + 0.5 * 0.05)


def test_loglik_scores_taught_scans_highest_under_their_own_feature(world) -> None:  # type: ignore[no-untyped-def]
    ranges, _, _, training = world
    for config in (PAPER, Config()):  # the plain and the robust kernels
        model = fit(ranges, LASER, training, config)
        ll = loglik(model, ranges)
        rows = list(model.features)
        assert ll.shape == (len(ranges), len(rows) + int(config.none_class))
        assert np.isfinite(ll).all()
        for feature, idx in training.items():
            best = np.argmax(ll[idx, : len(rows)], axis=1)
            assert np.mean([rows[b] == feature for b in best]) >= 0.9, (config, feature)


def test_config_choices_are_checked_once_when_made() -> None:
    for bad in ({"smoothing": "sideways"}, {"none_model": "nothing"}, {"temperature": "hot"}):
        with pytest.raises(ToolkitError, match=next(iter(bad))):
            Config(**bad)  # type: ignore[arg-type]
    with pytest.raises(ToolkitError, match="robust"):
        Config(robust=1.0)
