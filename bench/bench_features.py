"""Feature classification speed: 1,000,000 scans x 181 beams against 5 features (target < 5 s).

Scans are the simulated building's (4000 scans, with no-returns) tiled to the size; the model
is learnt from the regions of its first five places (10 scans each), one Gaussian per beam and
feature; a last row keeps the regions' two spans per feature as two components each (a
mixture: twice the work). Rows: the paper's literal per-scan model (the Gaussian
log-likelihood as one matrix product per chunk); robust beams and the "none" class (a compiled
kernel over scans in parallel; tempered posteriors); with the HMM forward filter along the
path (streaming); the per-beam model's forward-backward with the evidence length (the former
default); the last default (descriptors, logistic regression, per-beam term); the default
(descriptors and their context along the path, extremely randomised trees; docs/places.md)
alone, with the per-beam term and with the evidence pooled by position over the log (an
expert setting: the tiled log passes every spot 250 times); and `--none-model surroundings` (lateral 2), with one and two components per
feature.
Median of 3 runs after a warm-up on a small slice (compiles the kernels).
`BENCH_FEATURES_ROWS="toolkit default:"` runs only the rows whose name holds that text.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from toolkit.features import PAPER, Config, classify, fit
from toolkit.features.evaluate import BEAMS, LATERAL2, LOGISTIC
from toolkit.features.regions import spans_from_frame, training_indices

SCANS = 1_000_000
REPEATS = 3
FEATURES = 5


def _median_seconds(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median wall and CPU seconds (CPU: all threads of this process; on a shared machine the
    wall time also holds the waiting for a core)."""
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)), float(np.median(cpu))


def run(out: Path, quick: bool) -> list[dict[str, object]]:
    from toolkit.sim import simulate

    sim = simulate("building", seed=0)
    ds = sim.dataset
    spans = spans_from_frame(sim.regions, ds.t)
    taught = list(training_indices(spans))[:FEATURES]
    spans = [s for s in spans if s.feature in taught]
    training = training_indices(spans)
    assert len(training) == FEATURES
    n = 100_000 if quick else SCANS
    ranges = np.ascontiguousarray(np.resize(ds.ranges, (n, ds.n_beams)))
    assert ds.groundtruth is not None
    poses = np.resize(ds.groundtruth[["x", "y", "theta"]].to_numpy(), (n, 3))
    rows: list[dict[str, object]] = []
    configs = [
        ("paper (literal, matrix product)", PAPER, None),
        ("per-beam: robust + none, no smoothing", dataclasses.replace(BEAMS, smoothing="none"), None),
        ("per-beam: + HMM forward filter (streaming)", dataclasses.replace(BEAMS, smoothing="forward", evidence_length=None), poses),
        ("per-beam: forward-backward, evidence length (the former default)", BEAMS, poses),
        ("per-beam: two components per feature (the regions' spans)", BEAMS, poses),
        ("last default: descriptors, logistic regression + per-beam term, HMM", LOGISTIC, poses),
        ("toolkit default: descriptors + context, trees, HMM", Config(), poses),
        ("toolkit default + per-beam term 1", dataclasses.replace(Config(), beam_term=1.0), poses),
        ("toolkit default + revisits pooled by position (place_pool 4, all scans taking them)", dataclasses.replace(Config(), place_pool=4.0, place_pool_into="all"), poses),
        ("--none-model surroundings (lateral 2, as its spans choose)", LATERAL2, poses),
        ("--none-model surroundings, two components per feature", LATERAL2, poses),
]  # fmt: skip
    wanted = os.environ.get("BENCH_FEATURES_ROWS", "")  # e.g. "toolkit default:" (a substring)
    for name, config, scan_poses in configs:
        if wanted and wanted not in name:
            continue
        components = spans if "two components" in name else None
        model = fit(ds.ranges, ds.laser, training, config, components, poses[: ds.n_scans])
        classify(model, ranges[:2000], None if scan_poses is None else scan_poses[:2000])
        seconds, cpu = _median_seconds(partial(classify, model, ranges, scan_poses), REPEATS)
        rows.append(
            {
                "name": name,
                "scans": n,
                "beams": ds.n_beams,
                "features": FEATURES,
                "components": len(model.features),
                "classes": len(model.classes),
                "seconds_median": round(seconds, 3),
                "cpu_seconds_median": round(cpu, 3),
                "load_average": round(os.getloadavg()[0], 1),
                "scans_per_s": round(n / seconds),
                "target_s": 5.0 * n / SCANS,
                "met": seconds < 5.0 * n / SCANS,
            }
        )
    return rows
