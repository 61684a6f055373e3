"""Scores for labelled scans: balanced accuracy over the classes present (the "none" class
counts as one) and the top-label expected calibration error."""

from __future__ import annotations

import numpy as np


def balanced_accuracy(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Mean over the true classes present of the share of their scans labelled right."""
    truth, predicted = np.asarray(truth).astype(str), np.asarray(predicted).astype(str)
    classes = np.unique(truth)
    if len(classes) == 0:
        return float("nan")
    recalls = [float(np.mean(predicted[truth == c] == c)) for c in classes]
    return float(np.mean(recalls))


def per_class_recall(truth: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    truth, predicted = np.asarray(truth).astype(str), np.asarray(predicted).astype(str)
    return {str(c): float(np.mean(predicted[truth == c] == c)) for c in np.unique(truth)}


def expected_calibration_error(
    confidence: np.ndarray, correct: np.ndarray, bins: int = 15
) -> float:
    """Top-label ECE: sum over equal-width confidence bins of the share of scans in the bin
    times |accuracy - mean confidence| in it."""
    confidence = np.asarray(confidence, dtype=np.float64)
    correct = np.asarray(correct, dtype=np.float64)
    if len(confidence) == 0:
        return float("nan")
    which = np.clip(np.ceil(confidence * bins).astype(int) - 1, 0, bins - 1)
    conf = np.bincount(which, weights=confidence, minlength=bins)
    acc = np.bincount(which, weights=correct, minlength=bins)
    return float(np.abs(acc - conf).sum() / len(confidence))
