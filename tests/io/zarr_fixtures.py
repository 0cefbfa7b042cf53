# SPDX-License-Identifier: Apache-2.0
"""Zarr fixtures for tests/io/zarr_stack_test.cpp, written by writers independent of
hisnegs: Debian's python3-zarr (Zarr v2, every compressor numcodecs has) and, for
Zarr v3 and sharding (which zarr-python 2 does not write), chunks encoded here with
numcodecs, zlib and gzip and laid out as the v3 specification says. Writes
manifest.json: per fixture the folder, the read options, the expected shape
(x, y, z), spacing (µm) and raw values (NAME.f32: float32, x fastest), or the
error a reader must give.

Run: /usr/bin/python3 zarr_fixtures.py OUT_DIR
"""
import gzip
import json
import os
import struct
import sys
import zlib

import numcodecs
import numpy as np
import zarr

out = sys.argv[1]
os.makedirs(out, exist_ok=True)
os.chdir(out)
rng = np.random.default_rng(7)
manifest = []


def stack(shape, dtype):
    if np.dtype(dtype).kind == "f":
        return rng.normal(100.0, 30.0, shape).astype(dtype)
    hi = 200 if np.dtype(dtype).itemsize == 1 else 60000
    lo = -3000 if np.dtype(dtype).kind == "i" else 0
    return rng.integers(lo, hi, shape).astype(dtype)


def expect(name, folder, zyx, spacing=(1.0, 1.0, 1.0), **options):
    """zyx: the stack hisnegs must read (z, y, x)."""
    zyx = np.ascontiguousarray(zyx, dtype=np.float32)
    zyx.tofile(name + ".f32")
    manifest.append({"name": name, "path": folder, "options": options, "shape": [zyx.shape[2], zyx.shape[1], zyx.shape[0]],
                     "spacing": list(spacing), "values": name + ".f32"})


def refuse(name, folder, error, **options):
    manifest.append({"name": name, "path": folder, "options": options, "error": error})


# --- Zarr v2 by zarr-python: every compressor, both key separators, the dtypes ---
base = stack((9, 21, 34), "<u2")
compressors = {"none": None, "zlib": numcodecs.Zlib(level=3), "gzip": numcodecs.GZip(level=5),
               "zstd": numcodecs.Zstd(level=3)}
for cname in numcodecs.blosc.list_compressors():
    for shuffle in (numcodecs.Blosc.NOSHUFFLE, numcodecs.Blosc.SHUFFLE, numcodecs.Blosc.BITSHUFFLE):
        compressors["blosc-%s-%d" % (cname, shuffle)] = numcodecs.Blosc(cname=cname, clevel=5, shuffle=shuffle)
for label, comp in compressors.items():
    for sep in (".", "/"):
        folder = "v2-%s-%s.zarr" % (label, "dot" if sep == "." else "slash")
        store = zarr.DirectoryStore(folder, dimension_separator=sep)
        a = zarr.create(shape=base.shape, chunks=(4, 8, 16), dtype="<u2", compressor=comp, store=store,
                        fill_value=0, overwrite=True)
        a[:] = base
        expect(folder, folder, base)

for dtype in ("|u1", "<u2", ">u2", "<i2", ">i2", "<f4", ">f4"):
    v = stack((5, 13, 17), dtype)
    folder = "v2-dtype-%s.zarr" % dtype.replace("<", "le").replace(">", "be").replace("|", "")
    a = zarr.open(folder, mode="w", shape=v.shape, chunks=(2, 8, 8), dtype=dtype,
                  compressor=numcodecs.Blosc(cname="zstd", shuffle=numcodecs.Blosc.SHUFFLE))
    a[:] = v
    expect(folder, folder, v)

# Chunks never written read as fill_value.
v = np.full((6, 16, 16), 77, dtype="<u2")
a = zarr.open("v2-fill.zarr", mode="w", shape=v.shape, chunks=(3, 8, 8), dtype="<u2", fill_value=77)
a[0:3, 0:8, 0:8] = stack((3, 8, 8), "<u2")
v[0:3, 0:8, 0:8] = a[0:3, 0:8, 0:8]
expect("v2-fill.zarr", "v2-fill.zarr", v)

# Refused: F order, a filter, an unread dtype, a 2D array.
zarr.open("v2-forder.zarr", mode="w", shape=(4, 8, 8), chunks=(2, 4, 4), dtype="<u2", order="F")[:] = 1
refuse("v2-forder.zarr", "v2-forder.zarr", "order")
zarr.open("v2-filter.zarr", mode="w", shape=(4, 8, 8), chunks=(2, 4, 4), dtype="<u2",
          filters=[numcodecs.Delta(dtype="<u2")])[:] = 1
refuse("v2-filter.zarr", "v2-filter.zarr", "filters")
zarr.open("v2-int32.zarr", mode="w", shape=(4, 8, 8), chunks=(2, 4, 4), dtype="<i4")[:] = 1
refuse("v2-int32.zarr", "v2-int32.zarr", "dtype")
zarr.open("v2-2d.zarr", mode="w", shape=(8, 8), chunks=(4, 4), dtype="<u2")[:] = 1
refuse("v2-2d.zarr", "v2-2d.zarr", "axes")

# --- OME-NGFF v0.4 multiscale group (t, c, z, y, x; units), by zarr-python ---
tc = stack((2, 3, 7, 24, 20), "<u2")
g = zarr.open_group("ome04.ome.zarr", mode="w")
levels = [tc, tc[:, :, :, ::2, ::2]]
datasets = []
for i, lv in enumerate(levels):
    g.create_dataset(str(i), data=lv, chunks=(1, 1, 4, 8, 8), compressor=numcodecs.Blosc(cname="lz4"))
    f = 2 ** i
    datasets.append({"path": str(i), "coordinateTransformations": [
        {"type": "scale", "scale": [1.0, 1.0, 2000.0, 250.0 * f, 250.0 * f]}]})
g.attrs["multiscales"] = [{"version": "0.4", "name": "t", "axes": [
    {"name": "t", "type": "time", "unit": "second"}, {"name": "c", "type": "channel"},
    {"name": "z", "type": "space", "unit": "nanometer"}, {"name": "y", "type": "space", "unit": "nanometer"},
    {"name": "x", "type": "space", "unit": "nanometer"}], "datasets": datasets}]
expect("ome04-t1-c2", "ome04.ome.zarr", tc[1, 2], (0.25, 0.25, 2.0), channel=2, timepoint=1)
expect("ome04-level1", "ome04.ome.zarr", levels[1][0, 1], (0.5, 0.5, 2.0), channel=1, timepoint=0, level=1)
expect("ome04-array", "ome04.ome.zarr/1", levels[1][1, 0], (0.5, 0.5, 2.0), channel=0, timepoint=1)
refuse("ome04-no-channel", "ome04.ome.zarr", "--channel", timepoint=0)
refuse("ome04-level-range", "ome04.ome.zarr", "--level 2", channel=0, timepoint=0, level=2)
refuse("ome04-channel-range", "ome04.ome.zarr", "--channel 3", channel=3, timepoint=0)


# --- Zarr v3, laid out by hand (chunks by numcodecs, zlib, gzip) ---
def crc32c(data):
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0x82F63B78 if crc & 1 else crc >> 1
    return crc ^ 0xFFFFFFFF


def encode(raw, codecs):
    for c in codecs:
        name, conf = c["name"], c.get("configuration", {})
        if name == "gzip":
            raw = gzip.compress(raw, conf.get("level", 5))
        elif name == "zstd":
            raw = numcodecs.Zstd(level=conf.get("level", 3)).encode(raw)
        elif name == "blosc":
            shuffle = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}[conf["shuffle"]]
            raw = numcodecs.Blosc(cname=conf["cname"], clevel=conf["clevel"], shuffle=shuffle).encode(
                np.frombuffer(raw, dtype="u%d" % conf["typesize"]))
        elif name == "crc32c":
            raw = raw + struct.pack("<I", crc32c(raw))
    return bytes(raw)


def chunk_bytes(block, codecs):
    """block: the chunk's values (C order of the chunk shape), through the array codecs."""
    endian = "<"
    for c in codecs:
        if c["name"] == "transpose":
            block = np.transpose(block, c["configuration"]["order"])
        if c["name"] == "bytes":
            endian = ">" if c.get("configuration", {}).get("endian") == "big" else "<"
    b = np.ascontiguousarray(block).astype(block.dtype.newbyteorder(endian)).tobytes()
    return encode(b, [c for c in codecs if c["name"] not in ("transpose", "bytes")])


def padded(v, origin, shape):
    block = np.zeros(shape, dtype=v.dtype)
    sl = tuple(slice(o, min(o + s, n)) for o, s, n in zip(origin, shape, v.shape))
    part = v[sl]
    block[tuple(slice(0, p) for p in part.shape)] = part
    return block


def grid(shape, chunk):
    return np.ndindex(*[(n + c - 1) // c for n, c in zip(shape, chunk)])


def write_v3(folder, v, chunk, codecs, keys="default", shard_inner=None, inner_codecs=None, index_at="end",
             skip=(), attributes=None, dtype_name=None, fill=0, around=None):
    os.makedirs(folder, exist_ok=True)
    outer = codecs
    if shard_inner is not None:
        outer = [{"name": "sharding_indexed", "configuration": {
            "chunk_shape": list(shard_inner), "codecs": inner_codecs,
            "index_codecs": [{"name": "bytes", "configuration": {"endian": "little"}}, {"name": "crc32c"}],
            "index_location": index_at}}]
        if around:  # codecs placed around the sharding codec (refused by hisnegs)
            outer = around[0] + outer + around[1]
    meta = {"zarr_format": 3, "node_type": "array", "shape": list(v.shape), "data_type": dtype_name or str(v.dtype),
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": list(chunk)}},
            "chunk_key_encoding": {"name": keys, "configuration": {"separator": "/" if keys == "default" else "."}},
            "fill_value": fill, "codecs": outer, "attributes": attributes or {}}
    with open(os.path.join(folder, "zarr.json"), "w") as f:
        json.dump(meta, f)
    for idx in grid(v.shape, chunk):
        if idx in skip:
            continue
        origin = [i * c for i, c in zip(idx, chunk)]
        key = ("c/" + "/".join(map(str, idx))) if keys == "default" else ".".join(map(str, idx))
        path = os.path.join(folder, key)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        block = padded(v, origin, chunk)
        if shard_inner is None:
            data = chunk_bytes(block, codecs)
        else:
            payload, index = b"", []
            inner_grid = list(np.ndindex(*[c // s for c, s in zip(chunk, shard_inner)]))
            base_offset = 0 if index_at == "end" else 16 * len(inner_grid) + 4
            for j, inner in enumerate(inner_grid):
                if j % 3 == 1:  # every third inner chunk left empty: the fill value
                    index.append((2 ** 64 - 1, 2 ** 64 - 1))
                    block[tuple(slice(i * s, (i + 1) * s) for i, s in zip(inner, shard_inner))] = 0
                    continue
                sub = block[tuple(slice(i * s, (i + 1) * s) for i, s in zip(inner, shard_inner))]
                b = chunk_bytes(sub, inner_codecs)
                index.append((base_offset + len(payload), len(b)))
                payload += b
            raw_index = b"".join(struct.pack("<QQ", o, n) for o, n in index)
            raw_index += struct.pack("<I", crc32c(raw_index))
            data = payload + raw_index if index_at == "end" else raw_index + payload
            # what a reader must see: the block with its empty inner chunks
            sl = tuple(slice(o, min(o + c, n)) for o, c, n in zip(origin, chunk, v.shape))
            v[sl] = block[tuple(slice(0, s.stop - s.start) for s in sl)]
        with open(path, "wb") as f:
            f.write(data)
    return v


bytes_le = [{"name": "bytes", "configuration": {"endian": "little"}}]
v = stack((10, 19, 23), "uint16")
for label, codecs in {
        "gzip": bytes_le + [{"name": "gzip", "configuration": {"level": 5}}],
        "zstd": bytes_le + [{"name": "zstd", "configuration": {"level": 3, "checksum": False}}],
        "blosc": bytes_le + [{"name": "blosc", "configuration": {"cname": "lz4", "clevel": 5, "shuffle": "bitshuffle",
                                                                 "typesize": 2, "blocksize": 0}}],
        "big-crc": [{"name": "bytes", "configuration": {"endian": "big"}}, {"name": "crc32c"}],
        "transpose": [{"name": "transpose", "configuration": {"order": [2, 0, 1]}}] + bytes_le +
                     [{"name": "zstd", "configuration": {"level": 1}}]}.items():
    folder = "v3-%s.zarr" % label
    expect(folder, folder, write_v3(folder, v.copy(), (4, 8, 8), codecs))
folder = "v3-v2keys.zarr"
expect(folder, folder, write_v3(folder, v.copy(), (4, 8, 8), bytes_le, keys="v2"))
w = v.copy()
w[0:4, 0:8, 0:8] = 0
folder = "v3-missing.zarr"
expect(folder, folder, write_v3(folder, v.copy(), (4, 8, 8), bytes_le, skip={(0, 0, 0)}) * 0 + w)

inner = bytes_le + [{"name": "blosc", "configuration": {"cname": "zstd", "clevel": 5, "shuffle": "shuffle",
                                                        "typesize": 2, "blocksize": 0}}]
for at in ("end", "start"):
    folder = "v3-shard-%s.zarr" % at
    expect(folder, folder, write_v3(folder, stack((10, 19, 23), "uint16"), (8, 16, 16), None, shard_inner=(4, 8, 8),
                                    inner_codecs=inner, index_at=at))

# OME-NGFF v0.5: a v3 group whose attributes.ome holds the multiscales; sharded level 0.
os.makedirs("ome05.ome.zarr", exist_ok=True)
v5 = stack((2, 12, 32, 32), "uint8")
lvl0 = write_v3("ome05.ome.zarr/s0", v5.copy(), (1, 8, 16, 16), None, shard_inner=(1, 4, 8, 8),
                inner_codecs=bytes_le + [{"name": "gzip", "configuration": {"level": 1}}])
lvl1 = write_v3("ome05.ome.zarr/s1", np.ascontiguousarray(v5[:, :, ::2, ::2]), (1, 6, 16, 16), bytes_le)
ome = {"version": "0.5", "multiscales": [{"name": "v5", "axes": [
    {"name": "c", "type": "channel"}, {"name": "z", "type": "space", "unit": "micrometer"},
    {"name": "y", "type": "space", "unit": "micrometer"}, {"name": "x", "type": "space", "unit": "micrometer"}],
    "datasets": [{"path": "s0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1.5, 0.4, 0.4]}]},
                 {"path": "s1", "coordinateTransformations": [{"type": "scale", "scale": [1, 1.5, 0.8, 0.8]}]}],
    "coordinateTransformations": [{"type": "scale", "scale": [1, 2, 1, 1]}]}]}
with open("ome05.ome.zarr/zarr.json", "w") as f:
    json.dump({"zarr_format": 3, "node_type": "group", "attributes": {"ome": ome}}, f)
expect("ome05-c1", "ome05.ome.zarr", lvl0[1], (0.4, 0.4, 3.0), channel=1)
expect("ome05-level1", "ome05.ome.zarr", lvl1[0], (0.8, 0.8, 3.0), channel=0, level=1)

# Refused v3: an unknown codec, a dataset path leaving the folder, a bad shard index.
os.makedirs("v3-unknown.zarr", exist_ok=True)
write_v3("v3-unknown.zarr", v.copy(), (4, 8, 8), bytes_le + [{"name": "lzma"}])
refuse("v3-unknown.zarr", "v3-unknown.zarr", "codec \"lzma\"")
os.makedirs("escape.ome.zarr", exist_ok=True)
with open("escape.ome.zarr/.zgroup", "w") as f:
    json.dump({"zarr_format": 2}, f)
with open("escape.ome.zarr/.zattrs", "w") as f:
    json.dump({"multiscales": [{"version": "0.4", "axes": ["z", "y", "x"], "datasets": [{"path": "../v2-fill.zarr"}]}]}, f)
refuse("escape.ome.zarr", "escape.ome.zarr", "leaves the folder")


# Bad metadata and chunks, each refused in one line naming the file and the problem.
def v2_meta(folder, **changes):
    zarr.open(folder, mode="w", shape=(4, 8, 8), chunks=(2, 4, 4), dtype="<u2", compressor=None)[:] = 3
    with open(os.path.join(folder, ".zarray")) as f:
        meta = json.load(f)
    meta.update(changes)
    with open(os.path.join(folder, ".zarray"), "w") as f:
        json.dump(meta, f)


os.makedirs("bad-json.zarr", exist_ok=True)
with open("bad-json.zarr/.zarray", "w") as f:
    f.write('{"zarr_format": 2, "shape": [4, 8')
refuse("bad-json.zarr", "bad-json.zarr", "is not valid JSON")
os.makedirs("bad-json3.zarr", exist_ok=True)
with open("bad-json3.zarr/zarr.json", "w") as f:
    f.write('{"zarr_format": 3, "node_type": "array", "shape": [4, 8, 8], "data_type": "uint16"}')
refuse("bad-json3.zarr", "bad-json3.zarr", "has no field \"chunk_grid\"")
v2_meta("bad-chunk0.zarr", chunks=[2, 0, 4])
refuse("bad-chunk0.zarr", "bad-chunk0.zarr", "chunks = [2,0,4]")
v2_meta("bad-huge.zarr", shape=[2147483647, 2147483647, 2147483647], chunks=[1, 1, 1])
refuse("bad-huge.zarr", "bad-huge.zarr", "more than 2^62")
v2_meta("bad-axes.zarr")
os.makedirs("bad-axes.ome.zarr", exist_ok=True)
os.rename("bad-axes.zarr", "bad-axes.ome.zarr/0")
with open("bad-axes.ome.zarr/.zattrs", "w") as f:
    json.dump({"multiscales": [{"version": "0.4", "axes": [{"name": "z", "type": "space"}, {"name": "y", "type": "space"},
                                                          {"name": "q", "type": "space"}],
                                "datasets": [{"path": "0"}]}]}, f)
with open("bad-axes.ome.zarr/.zgroup", "w") as f:
    json.dump({"zarr_format": 2}, f)
refuse("bad-axes.ome.zarr", "bad-axes.ome.zarr", "do not name x, y and z once each")
for label, scale in {"zero": [0.0, 1.0, 1.0], "negative": [1.0, -2.0, 1.0], "nan": ["NaN", 1.0, 1.0]}.items():
    folder = "bad-scale-%s.ome.zarr" % label
    g = zarr.open_group(folder, mode="w")
    g.create_dataset("0", data=np.ones((4, 8, 8), dtype="<u2"), chunks=(2, 4, 4))
    g.attrs["multiscales"] = [{"version": "0.4", "axes": ["z", "y", "x"], "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": scale}]}]}]
    refuse(folder, folder, "scale" if label != "nan" else "has the wrong type")
os.makedirs("bad-level.ome.zarr", exist_ok=True)
with open("bad-level.ome.zarr/.zattrs", "w") as f:
    json.dump({"multiscales": [{"version": "0.4", "axes": ["z", "y", "x"], "datasets": [{"path": "0"}]}]}, f)
refuse("bad-level.ome.zarr", "bad-level.ome.zarr", "holds no Zarr array")
v2_meta("bad-short.zarr")
with open("bad-short.zarr/0.0.0", "r+b") as f:
    f.truncate(10)
refuse("bad-short.zarr", "bad-short.zarr", "holds 10 bytes, the chunk 64")
v2_meta("bad-long.zarr")
with open("bad-long.zarr/1.1.1", "ab") as f:
    f.write(b"xx")
refuse("bad-long.zarr", "bad-long.zarr", "holds 66 bytes for a chunk; at most 64 can encode it")
v2_meta("bad-sep.zarr", dimension_separator="\\")
refuse("bad-sep.zarr", "bad-sep.zarr", "dimension_separator")
v2_meta("bad-order-type.zarr", order=[2, 4, 4])  # a field of the wrong JSON type (found by fuzz_zarr)
refuse("bad-order-type.zarr", "bad-order-type.zarr", "has malformed metadata")
v2_meta("bad-zstd.zarr", compressor={"id": "zstd", "level": 1})
refuse("bad-zstd.zarr", "bad-zstd.zarr", "zstd: ")
write_v3("bad-shard-past.zarr", stack((8, 16, 16), "uint16"), (8, 16, 16), None, shard_inner=(4, 8, 8),
         inner_codecs=bytes_le)
with open("bad-shard-past.zarr/c/0/0/0", "r+b") as f:
    data = bytearray(f.read())
    n = 8
    index = bytearray(data[-(16 * n + 4):-4])
    index[0:8] = struct.pack("<Q", 10 ** 9)
    data[-(16 * n + 4):] = index + struct.pack("<I", crc32c(bytes(index)))
    f.seek(0)
    f.write(data)
refuse("bad-shard-past.zarr", "bad-shard-past.zarr", "lies past the file's end")

# Found by review: a checksum inside a compressor, a float fill value as its bits,
# bioformats2raw's layout (the multiscale image in series 0).
folder = "v3-crc-then-zstd.zarr"
expect(folder, folder, write_v3(folder, v.copy(), (4, 8, 8), bytes_le + [{"name": "crc32c"},
                                                                       {"name": "zstd", "configuration": {"level": 1}}]))
f32 = stack((6, 16, 16), "float32")
folder = "v3-hexfill.zarr"
write_v3(folder, f32.copy(), (3, 8, 8), bytes_le, fill="0x42f60000", skip={(1, 1, 1)})
f32[3:6, 8:16, 8:16] = 123.0
expect(folder, folder, f32)
os.makedirs("b2r.zarr", exist_ok=True)
with open("b2r.zarr/.zgroup", "w") as f:
    json.dump({"zarr_format": 2}, f)
with open("b2r.zarr/.zattrs", "w") as f:
    json.dump({"bioformats2raw.layout": 3}, f)
g = zarr.open_group("b2r.zarr/0", mode="w")
b2r = stack((5, 16, 16), "<u2")
g.create_dataset("0", data=b2r, chunks=(2, 8, 8))
g.attrs["multiscales"] = [{"version": "0.4", "axes": ["z", "y", "x"], "datasets": [
    {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [2.0, 0.5, 0.5]}]}]}]
expect("b2r.zarr", "b2r.zarr", b2r, (0.5, 0.5, 2.0))

# Refused by review: codecs around the sharding codec, an empty transpose, metadata
# nested a million deep, a chunk file far longer than its chunk, a bad index_location.
write_v3("bad-around-shard.zarr", v.copy(), (8, 16, 16), None, shard_inner=(4, 8, 8), inner_codecs=bytes_le,
         around=([{"name": "transpose", "configuration": {"order": [2, 1, 0]}}], []))
refuse("bad-around-shard.zarr", "bad-around-shard.zarr", "codecs around sharding_indexed")
write_v3("bad-empty-transpose.zarr", v.copy(), (4, 8, 8), bytes_le)
with open("bad-empty-transpose.zarr/zarr.json") as f:
    meta = json.load(f)
meta["codecs"] = [{"name": "transpose", "configuration": {"order": []}}] + bytes_le
with open("bad-empty-transpose.zarr/zarr.json", "w") as f:
    json.dump(meta, f)
refuse("bad-empty-transpose.zarr", "bad-empty-transpose.zarr", "is not a permutation of the axes")
os.makedirs("bad-deep.zarr", exist_ok=True)
with open("bad-deep.zarr/.zarray", "w") as f:
    f.write('{"zarr_format": 2, "fill_value": ' + "[" * 1000000 + "]" * 1000000 + "}")
refuse("bad-deep.zarr", "bad-deep.zarr", "nests JSON deeper than 64 levels")
v2_meta("bad-huge-chunk.zarr")
with open("bad-huge-chunk.zarr/0.0.0", "wb") as f:
    f.truncate(1 << 20)
refuse("bad-huge-chunk.zarr", "bad-huge-chunk.zarr", "can encode it")
write_v3("bad-index-location.zarr", v.copy(), (8, 16, 16), None, shard_inner=(4, 8, 8), inner_codecs=bytes_le)
with open("bad-index-location.zarr/zarr.json") as f:
    meta = json.load(f)
meta["codecs"][0]["configuration"]["index_location"] = "middle"
with open("bad-index-location.zarr/zarr.json", "w") as f:
    json.dump(meta, f)
refuse("bad-index-location.zarr", "bad-index-location.zarr", "index_location")

with open("manifest.json", "w") as f:
    json.dump(manifest, f, indent=1)
print("zarr fixtures: %d" % len(manifest))
