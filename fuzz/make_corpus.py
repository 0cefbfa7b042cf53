#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Seed corpora of the libFuzzer targets, generated (never fetched): small valid
and slightly malformed TIFF stacks, PLY checkpoints, cameras.json and configs.

Usage: make_corpus.py OUT_DIR  (writes OUT_DIR/{tiff,ply,cameras,config,zarr}/*).
Python 3 standard library only; the TIFF writer is hand-written so the seeds do
not depend on libtiff or on a hisnegs build. Output is deterministic.
"""
import json
import math
import struct
import sys
import zlib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# ---------------------------------------------------------------------------
# TIFF

SHORT, LONG, RATIONAL, ASCII, LONG8 = 3, 4, 5, 2, 16
TYPE_SIZE = {ASCII: 1, SHORT: 2, LONG: 4, RATIONAL: 8, LONG8: 8}
TYPE_CODE = {SHORT: "H", LONG: "I", LONG8: "Q"}


def packbits(data):
    """PackBits (TIFF compression 32773) with literal runs only: valid and tiny."""
    out = bytearray()
    for i in range(0, len(data), 128):
        chunk = data[i:i + 128]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def sample_bytes(values, bits, fmt, endian):
    code = {(8, 1): "B", (16, 1): "H", (32, 1): "I", (8, 2): "b", (16, 2): "h",
            (32, 3): "f", (64, 3): "d"}[(bits, fmt)]
    return struct.pack(endian + code * len(values), *values)


def tiff(nx=4, ny=3, pages=3, bits=8, fmt=1, samples=1, planar=1, photometric=None,
         compression=1, tile=0, rows_per_strip=0, description=None, resolution=None,
         resolution_unit=None, bigtiff=False, big_endian=False, value=None, page_shapes=None):
    """A multi-page TIFF as bytes. `value(page, sample, x, y)` gives the pixels;
    `page_shapes` optionally overrides (nx, ny) per page (a malformed stack)."""
    e = ">" if big_endian else "<"
    off_code = "Q" if bigtiff else "I"
    off_type = LONG8 if bigtiff else LONG
    if value is None:
        value = lambda p, s, x, y: (p * 31 + s * 7 + x * 3 + y * 5) % 251
    if photometric is None:
        photometric = 2 if samples == 3 else 1
    out = bytearray(b"MM" if big_endian else b"II")
    if bigtiff:
        out += struct.pack(e + "HHHQ", 43, 8, 0, 0)
        next_ptr = 8
    else:
        out += struct.pack(e + "HI", 42, 0)
        next_ptr = 4

    for page in range(pages):
        w, h = page_shapes[page] if page_shapes else (nx, ny)
        # Pixel data: strips (or tiles) of the page, one plane per sample when planar = 2.
        planes = samples if planar == 2 else 1
        per_pixel = 1 if planar == 2 else samples
        blocks = []
        for plane in range(planes):
            if tile:
                for ty in range(0, h, tile):
                    for tx in range(0, w, tile):
                        vals = []
                        for y in range(ty, ty + tile):
                            for x in range(tx, tx + tile):
                                for s in range(per_pixel):
                                    inside = x < w and y < h
                                    vals.append(value(page, plane + s, x, y) if inside else 0)
                        blocks.append(sample_bytes(vals, bits, fmt, e))
            else:
                rps = rows_per_strip or h
                for y0 in range(0, h, rps):
                    vals = [value(page, plane + s, x, y)
                            for y in range(y0, min(h, y0 + rps)) for x in range(w) for s in range(per_pixel)]
                    blocks.append(sample_bytes(vals, bits, fmt, e))
        if compression == 8:
            blocks = [zlib.compress(b) for b in blocks]
        elif compression == 32773:
            blocks = [packbits(b) for b in blocks]
        offsets = []
        for b in blocks:
            offsets.append(len(out))
            out += b
            if len(out) % 2:
                out += b"\0"

        tags = [(256, LONG, [w]), (257, LONG, [h]), (258, SHORT, [bits] * samples),
                (259, SHORT, [compression]), (262, SHORT, [photometric]),
                (277, SHORT, [samples]), (284, SHORT, [planar]), (339, SHORT, [fmt] * samples)]
        if page == 0 and description is not None:
            tags.append((270, ASCII, description.encode("latin-1") + b"\0"))
        if resolution is not None:
            tags.append((282, RATIONAL, [resolution[0]]))
            tags.append((283, RATIONAL, [resolution[1]]))
        if resolution_unit is not None:
            tags.append((296, SHORT, [resolution_unit]))
        counts = [len(b) for b in blocks]
        if tile:
            tags += [(322, LONG, [tile]), (323, LONG, [tile]),
                     (324, off_type, offsets), (325, LONG, counts)]
        else:
            tags += [(273, off_type, offsets), (278, LONG, [rows_per_strip or h]),
                     (279, LONG, counts)]
        tags.sort(key=lambda t: t[0])

        def payload(typ, vals):
            if typ == ASCII:
                return vals
            if typ == RATIONAL:
                return b"".join(struct.pack(e + "II", *rational(v)) for v in vals)
            return struct.pack(e + TYPE_CODE[typ] * len(vals), *vals)

        inline = 8 if bigtiff else 4
        # Out-of-line values first, then the IFD that points at them.
        entries = []
        for tag, typ, vals in tags:
            data = payload(typ, vals)
            count = len(vals)
            if len(data) > inline:
                pos = len(out)
                out += data
                if len(out) % 2:
                    out += b"\0"
                field = struct.pack(e + off_code, pos)
            else:
                field = data + b"\0" * (inline - len(data))
            entries.append((tag, typ, count, field))
        ifd = len(out)
        struct.pack_into(e + off_code, out, next_ptr, ifd)
        if bigtiff:
            out += struct.pack(e + "Q", len(entries))
            for tag, typ, count, field in entries:
                out += struct.pack(e + "HHQ", tag, typ, count) + field
            next_ptr = len(out)
            out += struct.pack(e + "Q", 0)
        else:
            out += struct.pack(e + "H", len(entries))
            for tag, typ, count, field in entries:
                out += struct.pack(e + "HHI", tag, typ, count) + field
            next_ptr = len(out)
            out += struct.pack(e + "I", 0)
    return bytes(out)


def rational(v):
    den = 1000 if v < 4e6 else 1
    return int(round(v * den)), den


def ome(nx, ny, z, c=1, t=1, order="XYZCT", extra=""):
    return ('<?xml version="1.0" encoding="UTF-8"?><OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06">'
            '<Image ID="Image:0"><Pixels ID="Pixels:0" DimensionOrder="%s" Type="uint8" SizeX="%d" SizeY="%d" '
            'SizeZ="%d" SizeC="%d" SizeT="%d"%s><TiffData/></Pixels></Image></OME>'
            % (order, nx, ny, z, c, t, extra))


def tiff_seeds():
    imagej = "ImageJ=1.11a\nimages=3\nslices=3\nunit=um\nspacing=2.5\nmin=0\nmax=255\n"
    s = {
        "u8.tif": tiff(),
        "u16.tif": tiff(bits=16, value=lambda p, s, x, y: 1000 * p + 17 * x + 3 * y),
        "f32.tif": tiff(bits=32, fmt=3, value=lambda p, s, x, y: 0.25 * p - 0.5 * x + y),
        "u16_big_endian.tif": tiff(big_endian=True, bits=16),
        "bigtiff.tif": tiff(bigtiff=True),
        "bigtiff_tiled.tif": tiff(bigtiff=True, nx=20, ny=18, tile=16, bits=16),
        "tiled.tif": tiff(nx=20, ny=17, tile=16),
        "strips.tif": tiff(ny=7, rows_per_strip=2),
        "deflate.tif": tiff(compression=8, bits=16),
        "packbits.tif": tiff(compression=32773),
        "rgb_contig.tif": tiff(samples=3),
        "rgb_planar.tif": tiff(samples=3, planar=2),
        "imagej.tif": tiff(description=imagej, resolution=(2.0, 2.0)),
        "imagej_hyperstack.tif": tiff(pages=6, description="ImageJ=1.11a\nimages=6\nchannels=2\nslices=3\n"
                                                          "hyperstack=true\nunit=micron\nspacing=0.5\n"),
        "imagej_mismatch.tif": tiff(description="ImageJ=1.11a\nimages=5\nslices=5\n"),
        "ome.tif": tiff(description=ome(4, 3, 3, extra=' PhysicalSizeX="0.3" PhysicalSizeY="0.3" '
                                                          'PhysicalSizeZ="1.5" PhysicalSizeZUnit="nm"')),
        "ome_xyczt.tif": tiff(pages=6, description=ome(4, 3, 3, c=2, order="XYCZT")),
        "resolution_cm.tif": tiff(resolution=(10000.0, 5000.0), resolution_unit=3),
        "single_page.tif": tiff(pages=1),
        "pages_differ.tif": tiff(page_shapes=[(4, 3), (4, 3), (5, 3)]),
        "f32_huge_values.tif": tiff(bits=32, fmt=3, value=lambda p, s, x, y: (-3e38 if (x + y + p) % 2 else 3e38)),
        "int16_signed.tif": tiff(bits=16, fmt=2),
        "f64.tif": tiff(bits=64, fmt=3),
    }
    good = s["u8.tif"]
    s["truncated.tif"] = good[: len(good) * 2 // 3]
    s["header_only.tif"] = good[:8]
    return s


# ---------------------------------------------------------------------------
# PLY checkpoints

PARAMS = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
          "intensity_logit"]
GAUSSIANS = [[0.1, -0.2, 0.3, -3.0, -2.5, -2.0, 1.0, 0.0, 0.0, 0.0, 0.5],
             [-0.4, 0.25, 0.0, -4.0, -4.0, -3.5, 0.7, 0.1, -0.7, 0.1, -1.0]]
META = ["hisnegs format_version 1", "hisnegs volume_shape 48 192 192", "hisnegs spacing_um 0.3 0.3 1",
        "hisnegs aspect 1 1 0.75", "hisnegs normalization minmax 0 254", "hisnegs fit_seconds 12.5"]


def ply(fmt="binary_little_endian", comments=META, props=None, rows=GAUSSIANS, count=None, extra=b"",
        element="vertex", body=None):
    props = props if props is not None else [("float", p) for p in PARAMS]
    head = "ply\nformat %s 1.0\n" % fmt
    head += "".join("comment %s\n" % c for c in comments)
    head += "element %s %d\n" % (element, len(rows) if count is None else count)
    head += "".join("property %s %s\n" % p for p in props)
    head += "end_header\n"
    if body is None:
        if fmt == "ascii":
            body = "".join(" ".join(repr(v) for v in r[:len(props)]) + "\n" for r in rows).encode()
        else:
            e = "<" if fmt == "binary_little_endian" else ">"
            codes = {"float": "f", "double": "d", "uchar": "B", "int": "i"}
            body = b"".join(struct.pack(e + "".join(codes[t] for t, _ in props), *r[:len(props)]) for r in rows)
    return head.encode() + body + extra


def ply_seeds():
    valid = ply()
    return {
        "valid.ply": valid,
        "empty_model.ply": ply(rows=[]),
        "ascii.ply": ply(fmt="ascii"),
        "big_endian.ply": ply(fmt="binary_big_endian"),
        "double.ply": ply(props=[("double", p) for p in PARAMS]),
        "extra_property.ply": ply(props=[("float", p) for p in PARAMS] + [("float", "f_dc_0")],
                                  rows=[r + [0.5] for r in GAUSSIANS]),
        "reordered.ply": ply(props=[("float", p) for p in reversed(PARAMS)], rows=[r[::-1] for r in GAUSSIANS]),
        "no_comments.ply": ply(comments=[]),
        "missing_property.ply": ply(props=[("float", p) for p in PARAMS[:-1]]),
        "wrong_type.ply": ply(props=[("int", p) if p == "x" else ("float", p) for p in PARAMS],
                              rows=[[1] + r[1:] for r in GAUSSIANS]),
        "newer_version.ply": ply(comments=["hisnegs format_version 2"]),
        "bad_meta.ply": ply(comments=["hisnegs volume_shape 1 -2 x", "hisnegs spacing_um 1 1"]),
        "zero_quaternion.ply": ply(rows=[r[:6] + [0.0, 0.0, 0.0, 0.0] + r[10:] for r in GAUSSIANS]),
        "truncated.ply": valid[:-7],
        "trailing_bytes.ply": ply(extra=b"\0\0\0\0"),
        "huge_count.ply": ply(count=4611686018427387904),
        "list_property.ply": ply(props=[("list uchar int", "vertex_indices")], rows=[], body=b""),
        "other_element.ply": ply(element="face"),
        "no_end_header.ply": b"ply\nformat ascii 1.0\nelement vertex 0\n",
        "crlf.ply": ply(fmt="ascii").replace(b"\n", b"\r\n"),
    }


# ---------------------------------------------------------------------------
# cameras.json


def rot_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


def cameras(**override):
    d = {"width": 64, "height": 48, "fx": 55.4, "fy": 55.4, "cx": 32.0, "cy": 24.0, "near": 0.01, "far": 10.0,
         "views": [{"name": "train_000", "R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                    "T": [0.0, 0.0, 2.7]},
                   {"name": "train_001", "R": rot_z(90.0), "T": [0.1, -0.2, 2.7]}]}
    d.update(override)
    return d


def camera_seeds():
    view = cameras()["views"][0]
    seeds = {
        "valid.json": cameras(),
        "one_view.json": cameras(views=[view]),
        "no_views.json": cameras(views=[]),
        "unknown_key.json": cameras(fov=50),
        "near_after_far.json": cameras(near=5.0, far=1.0),
        "not_rotation.json": cameras(views=[dict(view, R=[[2.0, 0, 0], [0, 1, 0], [0, 0, 1]])]),
        "float_width.json": cameras(width=64.5),
        "big_width.json": cameras(width=4294967297),
        "string_focal.json": cameras(fx="55"),
        "short_T.json": cameras(views=[dict(view, T=[0, 0])]),
    }
    out = {name: json.dumps(d, indent=1).encode() for name, d in seeds.items()}
    out["not_object.json"] = b"[1, 2, 3]"
    out["truncated.json"] = out["valid.json"][:100]
    out["nested.json"] = b'{"width": ' + b"[" * 64 + b"]" * 64 + b"}"
    return out


# ---------------------------------------------------------------------------
# configs: the shipped ones (every key) plus small malformed ones.


def config_seeds():
    out = {}
    for path in sorted((REPO / "configs").rglob("*.yaml")):
        out[str(path.relative_to(REPO / "configs")).replace("/", "_")] = path.read_bytes()
    out.update({
        "empty.yaml": b"",
        "one_key.yaml": b"camera:\n  width: 128\n",
        "flow.yaml": b"{volume: {spacing_um: [0.3, 0.3, 1.0], channel: 0}, train: {}}\n",
        "anchors.yaml": b"camera: &c\n  width: 64\n  height: 64\nraymarch: *c\n",
        "unknown_section.yaml": b"cameras:\n  width: 64\n",
        "unknown_key.yaml": b"camera:\n  widht: 64\n",
        "wrong_type.yaml": b"camera:\n  width: [1, 2]\n",
        "bad_enum.yaml": b"volume:\n  normalization: zscore\n",
        "out_of_range.yaml": b"volume:\n  percentile_lo: 150\n",
        "not_a_map.yaml": b"- volume\n- camera\n",
        "section_list.yaml": b"volume: [1, 2]\n",
        "complex_key.yaml": b"? [a, b]\n: 1\n",
        "invalid.yaml": b"volume:\n  channel: 0\n bad indent: [\n",
    })
    return out


def zarr_seeds():
    """Zarr arrays for fuzz_zarr: the metadata (.zarray or zarr.json), a NUL, then
    the bytes of chunk 0 (v2 key 0.0.0, v3 key c/0/0/0)."""
    import gzip
    import json
    import zlib

    def crc32c(data):
        crc = 0xFFFFFFFF
        for b in data:
            crc ^= b
            for _ in range(8):
                crc = (crc >> 1) ^ 0x82F63B78 if crc & 1 else crc >> 1
        return crc ^ 0xFFFFFFFF

    raw = bytes((7 * i) % 251 for i in range(2 * 4 * 4 * 2))  # 2x4x4 uint16
    def v2(compressor, data, dtype="<u2", **extra):
        meta = {"zarr_format": 2, "shape": [2, 4, 4], "chunks": [2, 4, 4], "dtype": dtype, "compressor": compressor,
                "fill_value": 0, "order": "C", "filters": None}
        meta.update(extra)
        return json.dumps(meta).encode() + b"\0" + data

    def v3(codecs, data, chunk=(2, 4, 4)):
        meta = {"zarr_format": 3, "node_type": "array", "shape": [2, 4, 4], "data_type": "uint16",
                "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": list(chunk)}},
                "chunk_key_encoding": {"name": "default"}, "fill_value": 0, "codecs": codecs}
        return json.dumps(meta).encode() + b"\0" + data

    le = [{"name": "bytes", "configuration": {"endian": "little"}}]
    index = b"".join(struct.pack("<QQ", o, 16) for o in (0, 16, 32, 48))
    shard = raw[:16] + raw[16:32] + raw[32:48] + raw[48:64] + index + struct.pack("<I", crc32c(index))
    sharding = [{"name": "sharding_indexed", "configuration": {
        "chunk_shape": [1, 2, 4], "codecs": le,
        "index_codecs": le + [{"name": "crc32c"}], "index_location": "end"}}]
    return {
        "v2_none.zarr": v2(None, raw),
        "v2_zlib.zarr": v2({"id": "zlib", "level": 1}, zlib.compress(raw)),
        "v2_gzip.zarr": v2({"id": "gzip", "level": 1}, gzip.compress(raw, mtime=0)),
        "v2_u8.zarr": v2(None, raw[:32], dtype="|u1"),
        "v2_f4_big.zarr": v2(None, raw * 2, dtype=">f4"),
        "v2_slash.zarr": v2(None, raw, dimension_separator="/"),
        "v2_order_list.zarr": v2(None, raw, order=[2, 4, 4]),  # a type_error escaped here once
        "v3_bytes.zarr": v3(le, raw),
        "v3_gzip_crc.zarr": v3(le + [{"name": "gzip", "configuration": {"level": 1}}, {"name": "crc32c"}],
                               gzip.compress(raw, mtime=0) + struct.pack("<I", crc32c(gzip.compress(raw, mtime=0)))),
        "v3_transpose.zarr": v3([{"name": "transpose", "configuration": {"order": [2, 1, 0]}}] + le, raw),
        "v3_shard.zarr": v3(sharding, shard),
    }


# ---------------------------------------------------------------------------


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: make_corpus.py OUT_DIR")
    root = Path(sys.argv[1])
    sets = {"tiff": tiff_seeds(), "ply": ply_seeds(), "cameras": camera_seeds(), "config": config_seeds(),
            "zarr": zarr_seeds()}
    for target, seeds in sets.items():
        folder = root / target
        folder.mkdir(parents=True, exist_ok=True)
        for old in folder.iterdir():
            old.unlink()
        for name, data in seeds.items():
            (folder / name).write_bytes(data)
        print("%s: %d seeds in %s" % (target, len(seeds), folder))


if __name__ == "__main__":
    main()
