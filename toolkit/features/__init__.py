"""Feature learning (paper Eq. 7-9): places taught from about ten scans each, found along the
whole log with calibrated probabilities.

    from toolkit.features import Config, fit, classify, read_regions, training_components
    spans = read_regions("regions.csv", ds.t)
    model = fit(ds.ranges, ds.laser, training_components(spans), Config(), spans)
    labels = classify(model, ds.ranges, poses)      # .prob (S x K), .label, .classes
"""

from __future__ import annotations

from toolkit.features.classify import Labels, classify
from toolkit.features.fitting import fit
from toolkit.features.likelihood import loglik
from toolkit.features.metrics import balanced_accuracy, expected_calibration_error
from toolkit.features.model import PAPER, Config, FeatureModel
from toolkit.features.regions import (
    Span,
    read_regions,
    spans_from_frame,
    training_components,
    training_indices,
)

__all__ = [
    "PAPER",
    "Config",
    "FeatureModel",
    "Labels",
    "Span",
    "balanced_accuracy",
    "classify",
    "expected_calibration_error",
    "fit",
    "loglik",
    "read_regions",
    "spans_from_frame",
    "training_components",
    "training_indices",
]
