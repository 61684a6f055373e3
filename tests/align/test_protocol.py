"""The random-cloud protocol of Table 2: per-trial rows and their summary."""

from __future__ import annotations

import numpy as np

from toolkit.align.protocol import random_cloud_trials, summarize


def test_trials_and_summary_agree() -> None:
    trials = random_cloud_trials(sizes=(100, 300), trials=3, repeats=1)
    assert len(trials) == 2 * 3 * 3
    summary = summarize(trials)
    gauss = trials[(trials["method"] == "gaussian") & (trials["points"] == 300)]["error_m"]
    row = summary[(summary["method"] == "gaussian") & (summary["points"] == 300)].iloc[0]
    assert np.isclose(row["error_m"], gauss.mean()) and np.isclose(row["error_std_m"], gauss.std())
    assert row["trials"] == 3
    # 1 cm noise on 300 points: the mean displacement is known to about 1 mm
    assert (trials.loc[trials["method"] == "gaussian", "error_m"] < 0.004).all()
    icp = summary[summary["method"] == "icp"]
    assert np.allclose(icp["speedup_vs_icp"], 1.0) and np.allclose(icp["error_vs_icp"], 1.0)
