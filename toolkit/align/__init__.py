"""Alignment: the paper's O(N) Gaussian alignment, ICP baselines and the scan matcher.

import toolkit
r = toolkit.align.gaussian(cur, prev)       # .shift, .variance, .weights
r = toolkit.align.icp(cur, prev)            # .transform, .shift
"""

from __future__ import annotations

from toolkit.align.gaussian import GaussianResult, gaussian
from toolkit.align.icp import IcpResult, icp

__all__ = ["GaussianResult", "IcpResult", "gaussian", "icp"]
