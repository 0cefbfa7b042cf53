#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Writes a TIFF stack as an OME-Zarr v0.4 multiscale pyramid (zarr-python 2).

    /usr/bin/python3 scripts/to_ome_zarr.py STACK.tif OUT.ome.zarr [--chunk 128]
        [--levels 3] [--spacing Z,Y,X] [--clevel 5]

Level 0 is the stack as stored (its dtype), blosc-zstd with byte shuffle, chunks
of --chunk voxels per axis; each further level halves every axis (the mean of
2 x 2 x 2 voxels; an odd last voxel is dropped) and doubles the spacing, so every
level fills the same physical box (CONVENTIONS' world box: what `hisnegs fit
--level N` and `fit --init` rely on). The stack is read and written in slabs of
--chunk pages, so memory stays near two slabs whatever the stack's size. Spacing
in µm: --spacing, else the TIFF's ImageJ `spacing=` and X/YResolution, else 1.
Nothing is written over an existing OUT: a temporary folder beside it is renamed
when complete. For stacks hisnegs reads as OME-Zarr (docs/file-formats.md);
bioformats2raw does the same for any format Bio-Formats reads.
"""
import argparse
import os
import shutil
import sys

try:
    import numpy as np
    import tifffile
    import zarr
    from numcodecs import Blosc
except ImportError as e:  # pragma: no cover
    sys.exit(f"to_ome_zarr.py: {e.name} is not installed for {sys.executable} "
             "(Debian: apt-get install python3-zarr python3-tifffile; or run /usr/bin/python3)")


def tiff_spacing(tif):
    """(z, y, x) µm from the TIFF's ImageJ metadata and resolution, else 1."""
    z = y = x = 1.0
    ij = tif.imagej_metadata or {}
    if "spacing" in ij:
        z = float(ij["spacing"])
    page = tif.pages[0]
    for tag, axis in (("XResolution", "x"), ("YResolution", "y")):
        if tag in page.tags:
            num, den = page.tags[tag].value
            if num > 0 and den > 0 and num != den:
                if axis == "x":
                    x = den / num
                else:
                    y = den / num
    return z, y, x


def halve(block):
    """The mean of 2 x 2 x 2 voxels, as the block's dtype (odd ends dropped)."""
    z, y, x = (n // 2 * 2 for n in block.shape)
    b = block[:z, :y, :x].astype(np.float32)
    m = b.reshape(z // 2, 2, y // 2, 2, x // 2, 2).mean(axis=(1, 3, 5))
    if np.issubdtype(block.dtype, np.integer):
        m = np.rint(m)
    return m.astype(block.dtype)


def write_pyramid(a, tmp):
    """The pyramid into the folder `tmp`; returns (levels, spacing)."""
    with tifffile.TiffFile(a.stack) as tif:
        series = tif.series[0]
        shape, dtype = series.shape, series.dtype
        if len(shape) != 3:
            sys.exit(f"to_ome_zarr.py: {a.stack}: a stack of shape {shape}, not Z x Y x X")
        spacing = tuple(float(v) for v in a.spacing.split(",")) if a.spacing else tiff_spacing(tif)
        comp = Blosc(cname="zstd", clevel=a.clevel, shuffle=Blosc.SHUFFLE)
        root = zarr.open_group(tmp, mode="w")
        chunks = (a.chunk,) * 3
        arrays = [root.create_dataset("0", shape=shape, chunks=chunks, dtype=dtype, compressor=comp,
                                      fill_value=0, write_empty_chunks=False)]
        for z0 in range(0, shape[0], a.chunk):
            z1 = min(shape[0], z0 + a.chunk)
            arrays[0][z0:z1] = tif.asarray(key=range(z0, z1)).reshape(z1 - z0, shape[1], shape[2])
            print(f"to_ome_zarr.py: level 0: pages {z1} of {shape[0]}", file=sys.stderr)
    for level in range(1, a.levels):
        src = arrays[-1]
        lshape = tuple(n // 2 for n in src.shape)
        if min(lshape) < 1:
            break
        dst = root.create_dataset(str(level), shape=lshape, chunks=chunks, dtype=dtype, compressor=comp,
                                  fill_value=0, write_empty_chunks=False)
        step = 2 * a.chunk
        for z0 in range(0, lshape[0] * 2, step):
            z1 = min(lshape[0] * 2, z0 + step)
            dst[z0 // 2:z1 // 2] = halve(src[z0:z1])
        arrays.append(dst)
        print(f"to_ome_zarr.py: level {level}: {lshape}", file=sys.stderr)
    datasets = [{"path": str(i), "coordinateTransformations": [
        {"type": "scale", "scale": [s * 2 ** i for s in spacing]}]} for i in range(len(arrays))]
    root.attrs["multiscales"] = [{
        "version": "0.4", "name": os.path.basename(a.stack),
        "axes": [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"],
        "datasets": datasets}]
    return len(arrays), spacing


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("stack")
    p.add_argument("out")
    p.add_argument("--chunk", type=int, default=128)
    p.add_argument("--levels", type=int, default=3)
    p.add_argument("--spacing", help="Z,Y,X in µm (default: the TIFF's, else 1)")
    p.add_argument("--clevel", type=int, default=5)
    a = p.parse_args()
    if a.chunk < 8 or a.levels < 1:
        sys.exit("to_ome_zarr.py: --chunk must be >= 8 and --levels >= 1")
    if os.path.exists(a.out):
        sys.exit(f"to_ome_zarr.py: {a.out} exists; not overwritten")
    tmp = a.out.rstrip("/") + ".partial"
    if os.path.exists(tmp):
        sys.exit(f"to_ome_zarr.py: {tmp} exists (an interrupted run's? remove it); not overwritten")
    try:
        levels, spacing = write_pyramid(a, tmp)
    except BaseException:  # a full disk, a bad stack or Ctrl-C: no partial folder left behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    os.rename(tmp, a.out)
    print(f"to_ome_zarr.py: wrote {a.out}: {levels} levels, spacing {spacing} µm", file=sys.stderr)


if __name__ == "__main__":
    main()
