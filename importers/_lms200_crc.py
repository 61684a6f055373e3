"""SICK's telegram CRC compiled with numba: one frame after the other, sequential per byte.

Kept apart from `importers.lms200` so that numba is imported (and the kernel loaded from its
cache) only when `-O crc=numba` asks for it.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)  # type: ignore[untyped-decorator,unused-ignore]
def crc_kernel(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    out = np.zeros(starts.shape[0], np.uint32)
    for i in range(starts.shape[0]):
        crc = 0
        prev = 0
        s = starts[i]
        for k in range(lengths[i]):
            b = int(buf[s + k])
            if crc & 0x8000:
                crc = ((crc & 0x7FFF) << 1) ^ 0x8005
            else:
                crc = (crc << 1) & 0xFFFF
            crc ^= b | (prev << 8)
            prev = b
        out[i] = crc
    return out
