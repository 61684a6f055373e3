"""Alignment: the paper's O(N) Gaussian alignment, ICP baselines and the scan matcher.

import toolkit
r = toolkit.align.gaussian(cur, prev)       # .shift, .variance, .weights
r = toolkit.align.icp(cur, prev)            # .transform, .shift
m = toolkit.align.match_pairs(ranges, seeds, laser)      # a whole log's scan pairs at once
s = toolkit.align.StreamMatcher(laser)      # one scan at a time: s.push(ranges, odometry)
"""

from __future__ import annotations

from toolkit.align.gaussian import GaussianResult, gaussian
from toolkit.align.icp import IcpResult, icp
from toolkit.align.scan import MatchConfig, PairMatches, StreamMatcher, match_pairs

__all__ = [
    "GaussianResult",
    "IcpResult",
    "MatchConfig",
    "PairMatches",
    "StreamMatcher",
    "gaussian",
    "icp",
    "match_pairs",
]
