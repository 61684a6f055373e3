"""File writers for point clouds and images, in numpy alone: binary PLY and PCD, and PNG.

No plotting or 3D library: a PNG is zlib-compressed rows (the format is four chunks), a
cloud is a header and one structured array written as it is. So writing a map costs about
what its bytes cost, and the commands that write one start without matplotlib or Open3D
(about 1.5 s of imports between them).

    rows = np.empty(n, CLOUD)                 # x y z red green blue t scan
    write_ply(f, rows) / write_pcd(f, rows)   # or the header once, then rows chunk by chunk
    write_png(path, rgb, {"Title": "..."})    # H x W x 3 uint8
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

#: A cloud's vertex: position (m, float32), colour (8-bit RGB), the time of its scan (s) and
#: the scan's index, packed without padding (as PLY and PCD store them).
CLOUD = np.dtype(
    [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
        ("t", "<f8"),
        ("scan", "<i4"),
    ]
)

# int, not uint, for the scan index: Open3D's tensor reader skips uint properties
_PLY_TYPES = {"<f4": "float", "<f8": "double", "|u1": "uchar", "<i4": "int"}

#: viridis (matplotlib's default colour map) at 17 evenly spaced points; linear between them
#: it is within 6 of 255 of the full map.
_VIRIDIS = np.array(
    [
        [68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141],
        [44, 114, 142], [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128],
        [63, 188, 115], [94, 201, 98], [132, 212, 75], [173, 220, 48], [216, 226, 25],
        [253, 231, 37],
    ],
    dtype=np.float64,
)  # fmt: skip


def viridis(u: np.ndarray) -> np.ndarray:
    """8-bit RGB (N x 3) of values `u` in [0, 1] (clipped) on the viridis colour map."""
    index = np.clip(np.asarray(u, dtype=np.float64) * 255.0 + 0.5, 0, 255).astype(np.intp)
    return VIRIDIS_LUT[index]


#: viridis as 256 8-bit RGB entries: `viridis(u)` is VIRIDIS_LUT[int(clip(255 u + 0.5, 0, 255))]
VIRIDIS_LUT = np.round(
    np.column_stack(
        [np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, 17), _VIRIDIS[:, c]) for c in range(3)]
    )
).astype(np.uint8)


def ply_header(n: int, comment: str = "laser-toolkit map") -> bytes:
    """Header of a binary little-endian PLY of `n` CLOUD vertices."""
    lines = ["ply", "format binary_little_endian 1.0", f"comment {comment}", f"element vertex {n}"]
    lines += [f"property {_PLY_TYPES[CLOUD[name].str]} {name}" for name in CLOUD.names or ()]
    return ("\n".join([*lines, "end_header"]) + "\n").encode("ascii")


def pcd_header(n: int) -> bytes:
    """Header of a binary PCD (v0.7, PCL and Open3D read it) of `n` CLOUD points: the colour
    is PCL's packed `rgb` (one uint32, 0x00RRGGBB)."""
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        "FIELDS x y z rgb t scan\nSIZE 4 4 4 4 8 4\nTYPE F F F U F I\nCOUNT 1 1 1 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    ).encode("ascii")


#: A PCD point: CLOUD with the colour packed into PCL's one uint32 `rgb` (0x00RRGGBB).
PCD = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4"), ("t", "<f8"), ("scan", "<i4")]
)


def pcd_rows(rows: np.ndarray) -> np.ndarray:
    """CLOUD rows in PCD's layout (colour packed into one uint32)."""
    out = np.empty(len(rows), PCD)
    for name in ("x", "y", "z", "t", "scan"):
        out[name] = rows[name]
    out["rgb"] = (
        (rows["red"].astype(np.uint32) << 16)
        | (rows["green"].astype(np.uint32) << 8)
        | rows["blue"].astype(np.uint32)
    )
    return out


def write_ply(f: BinaryIO, rows: np.ndarray) -> None:
    """A whole binary PLY of CLOUD `rows` to the open file `f`."""
    f.write(ply_header(len(rows)))
    f.write(np.ascontiguousarray(rows, CLOUD).tobytes())


def write_pcd(f: BinaryIO, rows: np.ndarray) -> None:
    """A whole binary PCD of CLOUD `rows` to the open file `f`."""
    f.write(pcd_header(len(rows)))
    f.write(pcd_rows(rows).tobytes())


def write_png(path: str | Path, rgb: np.ndarray, text: dict[str, str] | None = None) -> None:
    """An 8-bit RGB PNG of the H x W x 3 uint8 image `rgb` (row 0 at the top), with `text` as
    tEXt chunks (keyword: value, Latin-1). zlib level 1: a third of level 6's time, for a
    file about half again as large (a map is mostly white)."""
    image = np.ascontiguousarray(rgb, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"an RGB image is H x W x 3, not {image.shape}")
    height, width = image.shape[:2]
    raw = np.zeros((height, 1 + 3 * width), np.uint8)  # each row: filter type 0, then pixels
    raw[:, 1:] = image.reshape(height, -1)
    chunks = [_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))]
    for key, value in (text or {}).items():
        chunks.append(_chunk(b"tEXt", key.encode("latin-1") + b"\0" + value.encode("latin-1")))
    chunks.append(_chunk(b"IDAT", zlib.compress(raw.tobytes(), 1)))
    chunks.append(_chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + b"".join(chunks))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
