#!/usr/bin/python3
# SPDX-License-Identifier: Apache-2.0
"""The test stack of a background that varies across the stack: two neurons side by
side, a background-subtracted one (op1_neuron.tif, every background voxel 0) and a
raw one (op3_raw.tif, camera noise everywhere), as tiles of one acquisition would
be. Both are DIADEM OP stacks of the same spacing (0.3296 x 0.3296 x 0.9988 um);
the shallower one is padded with zero planes.

    /usr/bin/python3 scripts/mosaic.py [DATA_DIR] [OUT.tif]

DATA_DIR defaults to ../shared/data, OUT to mosaic_op1_op3raw.tif; the result is
62 x 512 x 1024 uint8 (op1 at x < 512, op3_raw at x >= 512), ImageJ spacing kept.
Needs Debian's python3-numpy and python3-tifffile."""
import os
import sys

import numpy as np
import tifffile

data = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data")
out = sys.argv[2] if len(sys.argv) > 2 else "mosaic_op1_op3raw.tif"
tiles = [tifffile.imread(os.path.join(data, name)) for name in ("op1_neuron.tif", "op3_raw.tif")]
depth = max(t.shape[0] for t in tiles)
padded = [np.concatenate([t, np.zeros((depth - t.shape[0],) + t.shape[1:], t.dtype)]) for t in tiles]
mosaic = np.concatenate(padded, axis=2)
tmp = out + ".part"
tifffile.imwrite(tmp, mosaic, imagej=True, resolution=(1 / 0.3296, 1 / 0.3296),
                 metadata={"spacing": 0.9988, "unit": "um", "axes": "ZYX"})
os.replace(tmp, out)
print(f"{out}: {mosaic.shape[0]} x {mosaic.shape[1]} x {mosaic.shape[2]} {mosaic.dtype}, "
      f"{100.0 * np.mean(mosaic == 0):.1f} % zeros")
