#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Builds a large model from real fits, as a whole-brain stand-in (numpy only).

    /usr/bin/python3 scripts/big_model.py OUT.ply MODEL.ply [MODEL.ply ...]
        --copies N [--spacing 2.2] [--seed 0]

N copies of the given checkpoints (e.g. fits of op1, op2 and op3_raw), each a
model chosen at random, turned by a uniform random rotation about its box's
centre and placed on a cubic grid of `--spacing` world units (each model fills
[-1, 1] at most) with a random offset of up to a tenth of the spacing. Centres
and quaternions are transformed; scales and intensities are kept, so every copy
is a real neuron's fit. The result is a hisnegs PLY checkpoint (its metadata:
the format version and the aggregation of the first model; no stack shape, since
it stands for no stack). 10 M Gaussians: about 500 copies of 20,000-Gaussian fits,
440 MB. docs/benchmarks.md "Level of detail" uses it; tests build a small one.
"""
import argparse
import math
import os
import sys

try:
    import numpy as np
except ImportError:  # pragma: no cover
    sys.exit(f"big_model.py: numpy is not installed for {sys.executable} (run /usr/bin/python3)")

NAMES = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "intensity_logit"]


def read_checkpoint(path):
    """(params (K, 11) float32, aggregation line or None) of a binary little-endian hisnegs PLY."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        sys.exit(f"big_model.py: {path}: not a PLY checkpoint (a .hgs: `hisnegs export` it as .ply first)")
    lines = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        sys.exit(f"big_model.py: {path}: not a binary little-endian PLY")
    props = [l.split()[-1] for l in lines if l.startswith("property ")]
    if props != NAMES or any(not l.startswith("property float ") for l in lines if l.startswith("property ")):
        sys.exit(f"big_model.py: {path}: properties {props} are not a hisnegs checkpoint's")
    count = [int(l.split()[-1]) for l in lines if l.startswith("element vertex ")]
    body = np.frombuffer(data, dtype="<f4", offset=end + len(b"end_header\n"))
    if not count or body.size != count[0] * 11:
        sys.exit(f"big_model.py: {path}: the body does not hold the vertices the header declares")
    aggregation = next((l for l in lines if l.startswith("comment hisnegs aggregation ")), None)
    return body.reshape(count[0], 11), aggregation


def random_quaternions(rng, n):
    """Uniform random unit quaternions (w, x, y, z) (Shoemake)."""
    u1, u2, u3 = rng.random(n), rng.random(n), rng.random(n)
    a, b = np.sqrt(1 - u1), np.sqrt(u1)
    return np.stack([b * np.cos(2 * np.pi * u3), a * np.sin(2 * np.pi * u2), a * np.cos(2 * np.pi * u2),
                     b * np.sin(2 * np.pi * u3)], axis=1)


def rotation_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def compose(q, r):
    """q ⊗ r for one q and many r (w, x, y, z)."""
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = r[:, 0], r[:, 1], r[:, 2], r[:, 3]
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)


def write_copies(path, header, models, picks, quats, side, a, rng):
    """The PLY: the header, then every copy turned and placed."""
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        for c in range(a.copies):
            params = models[picks[c]][0]
            cell = np.array([c % side, (c // side) % side, c // (side * side)], dtype=np.float64)
            centre = (cell - (side - 1) / 2) * a.spacing + rng.uniform(-0.1, 0.1, 3) * a.spacing
            r = rotation_matrix(quats[c])
            out = params.astype(np.float64)
            box_mid = (params[:, :3].min(axis=0) + params[:, :3].max(axis=0)) / 2
            out[:, :3] = (params[:, :3] - box_mid) @ r.T + centre
            out[:, 6:10] = compose(quats[c], params[:, 6:10].astype(np.float64))
            f.write(out.astype("<f4").tobytes())


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("models", nargs="+")
    p.add_argument("--copies", type=int, required=True)
    p.add_argument("--spacing", type=float, default=2.2)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    if a.copies < 1 or not a.spacing > 0:
        sys.exit("big_model.py: --copies must be >= 1 and --spacing > 0")
    if os.path.abspath(a.out) in {os.path.abspath(m) for m in a.models}:
        sys.exit(f"big_model.py: {a.out} is also an input; not overwritten")
    models = [read_checkpoint(m) for m in a.models]
    rng = np.random.default_rng(a.seed)
    side = math.ceil(a.copies ** (1 / 3))
    picks = rng.integers(0, len(models), a.copies)
    total = sum(models[i][0].shape[0] for i in picks)
    tmp = a.out + ".partial"
    if os.path.exists(tmp):
        sys.exit(f"big_model.py: {tmp} exists (an interrupted run's? remove it); not overwritten")
    header = ["ply", "format binary_little_endian 1.0", "comment hisnegs format_version 1"]
    if models[0][1]:
        header.append(models[0][1])
    header += [f"comment hisnegs source big_model.py: {a.copies} copies of {len(models)} models",
               f"element vertex {total}"] + [f"property float {n}" for n in NAMES] + ["end_header"]
    quats = random_quaternions(rng, a.copies)
    try:
        write_copies(tmp, header, models, picks, quats, side, a, rng)
    except BaseException:  # a full disk or Ctrl-C: no partial file left behind
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    os.replace(tmp, a.out)
    print(f"big_model.py: wrote {a.out}: {total} Gaussians in {a.copies} copies on a {side}^3 grid "
          f"(spacing {a.spacing}), {os.path.getsize(a.out) / 2**20:.1f} MiB", file=sys.stderr)


if __name__ == "__main__":
    main()
