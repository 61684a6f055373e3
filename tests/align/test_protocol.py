"""The random-cloud protocols of Table 2: per-trial rows and their summary."""

from __future__ import annotations

import numpy as np

from toolkit.align.protocol import DENSE, METHODS, PAPER, random_cloud_trials, summarize


def test_trials_and_summary_agree() -> None:
    trials = random_cloud_trials(sizes=(100, 300), trials=3, repeats=1, protocol=DENSE)
    assert len(trials) == 2 * 3 * 3
    assert set(trials["protocol"]) == {"dense"}
    summary = summarize(trials)
    gauss = trials[(trials["method"] == "gaussian") & (trials["points"] == 300)]["error_m"]
    row = summary[(summary["method"] == "gaussian") & (summary["points"] == 300)].iloc[0]
    assert np.isclose(row["error_m"], gauss.mean()) and np.isclose(row["error_std_m"], gauss.std())
    assert row["trials"] == 3 and row["protocol"] == "dense"
    # 1 cm noise on 300 points: the mean displacement is known to about 1 mm
    assert (trials.loc[trials["method"] == "gaussian", "error_m"] < 0.004).all()
    icp = summary[summary["method"] == "icp"]
    assert np.allclose(icp["speedup_vs_icp"], 1.0) and np.allclose(icp["error_vs_icp"], 1.0)


def test_the_papers_protocol_and_interleaved_methods() -> None:
    """Coordinates 0-100 m, shifts up to 1 m: both methods find the shift to within a few
    standard errors of the 5 cm noise; the methods alternate trial by trial."""
    trials = random_cloud_trials(sizes=(1000,), trials=4, repeats=1, protocol=PAPER)
    assert set(trials["protocol"]) == {"paper"}
    standard_error = PAPER.noise / np.sqrt(1000)  # per axis, of a mean of 1000 points
    for method in ("gaussian", "icp"):
        errors = trials.loc[trials["method"] == method, "error_m"]
        assert (errors < 6 * standard_error).all(), (method, errors.max())
    orders = [list(rows["method"]) for _, rows in trials.groupby("trial", sort=True)]
    assert orders[0] == list(METHODS) and orders[1] == list(reversed(METHODS))
    assert orders[2] == orders[0]
