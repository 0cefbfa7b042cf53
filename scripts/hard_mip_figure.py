#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""A row of MIPs at a display gain, side by side, as one greyscale PNG: the figure
docs/benchmarks.md "The hard MIP" shows (ground truth and models' hard MIPs of one
view at 3x gain, where dim halos show).

  /usr/bin/python3 scripts/hard_mip_figure.py OUT.png VIEW GAIN [--crop R0,R1,C0,C1] [--zoom N] A.tif B.tif ...

Each TIFF is a float32 stack of `hisnegs gt` (mips.tif) or `hisnegs render`
(render.tif); page VIEW of each (rows R0..R1-1, columns C0..C1-1 of it with
--crop) is drawn at value x GAIN, clipped to [0, 1], each pixel N x N with --zoom,
with a 4-pixel white gap between panels. Needs numpy and tifffile (Debian's
python3-numpy, python3-tifffile); the PNG is written with zlib alone."""
import struct
import sys
import zlib

import numpy as np
import tifffile


def write_png(path, grey):
    h, w = grey.shape
    raw = b"".join(b"\x00" + grey[r].tobytes() for r in range(h))

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def main(argv):
    if len(argv) < 5:
        sys.exit(__doc__)
    out, view, gain, rest = argv[1], int(argv[2]), float(argv[3]), argv[4:]
    crop, zoom = None, 1
    while rest and rest[0] in ("--crop", "--zoom"):
        if rest[0] == "--crop":
            crop = [int(v) for v in rest[1].split(",")]
        else:
            zoom = int(rest[1])
        rest = rest[2:]
    stacks = rest
    panels = []
    for path in stacks:
        pages = tifffile.imread(path)
        if pages.ndim == 2:
            pages = pages[None]
        if not 0 <= view < pages.shape[0]:
            sys.exit(f"{path}: no view {view} (it holds {pages.shape[0]})")
        page = pages[view].astype(np.float64)
        if crop:
            page = page[crop[0]:crop[1], crop[2]:crop[3]]
        page = np.kron(page, np.ones((zoom, zoom)))
        panels.append(np.clip(page * gain, 0.0, 1.0))
    h = max(p.shape[0] for p in panels)
    gap = np.ones((h, 4))
    row = []
    for i, p in enumerate(panels):
        if i:
            row.append(gap)
        row.append(np.pad(p, ((0, h - p.shape[0]), (0, 0)), constant_values=1.0))
    write_png(out, np.round(255 * np.hstack(row)).astype(np.uint8))


if __name__ == "__main__":
    main(sys.argv)
