"""Alignment: the paper's O(N) Gaussian alignment, ICP baselines and the scan matcher.

import toolkit
r = toolkit.align.gaussian(cur, prev)       # .shift, .variance, .weights
r = toolkit.align.icp(cur, prev)            # .transform, .shift
m = toolkit.align.match_pairs(ranges, seeds, laser)      # a whole log's scan pairs at once
s = toolkit.align.StreamMatcher(laser)      # one scan at a time: s.push(ranges, odometry)

The ICP names (`icp`, `IcpResult`, `match_pairs_icp`) load `toolkit.align.baselines` (Open3D
and scipy, about 1 s) on first use, so that the Gaussian matcher starts without them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from toolkit.align.gaussian import GaussianResult, gaussian
from toolkit.align.scan import MatchConfig, PairMatches, StreamMatcher, match_pairs

if TYPE_CHECKING:
    from toolkit.align.baselines import IcpResult, icp, match_pairs_icp

_BASELINES = ("IcpResult", "icp", "match_pairs_icp")


def __getattr__(name: str) -> object:
    """The ICP names, from `toolkit.align.baselines`, imported on first use."""
    if name in _BASELINES:
        return getattr(importlib.import_module("toolkit.align.baselines"), name)
    raise AttributeError(f"module 'toolkit.align' has no attribute {name!r}")


__all__ = [
    "GaussianResult",
    "IcpResult",
    "MatchConfig",
    "PairMatches",
    "StreamMatcher",
    "gaussian",
    "icp",
    "match_pairs",
    "match_pairs_icp",
]
