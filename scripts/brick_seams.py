#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
# usage: brick_seams.py DATA.tif WHOLE.tif BRICKED.tif CORE HALO OUT.png
# (WHOLE/BRICKED: `hisnegs export volume --model M --match-volume DATA -o X.tif`)
# Seam check: z-MIPs of the data and of two fits rasterized (export volume), brick faces marked,
# a profile across a face, and the RMSE near faces vs away from them for both fits.
import sys, numpy as np, tifffile
from PIL import Image, ImageDraw
data, whole, bricked, core, halo, out = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
V = tifffile.imread(data).astype(np.float32); V = (V - V.min()) / (V.max() - V.min())
W = tifffile.imread(whole).astype(np.float32); B = tifffile.imread(bricked).astype(np.float32)
print('shapes', V.shape, W.shape, B.shape)
nz, ny, nx = V.shape
near = np.zeros((ny, nx), bool)
for f in range(core, nx, core): near[:, max(0, f - halo):f + halo] = True
for f in range(core, ny, core): near[max(0, f - halo):f + halo, :] = True
def rmse(M, mask):
    d = (M - V)[:, mask]; return float(np.sqrt(np.mean(d * d)))
def psnr(M, mask):
    d = (M - V)[:, mask]; return float(10 * np.log10(1.0 / np.mean(d * d)))
for name, M in (('whole', W), ('bricked', B)):
    print(f'{name}: 3D PSNR near faces (within {halo} voxels) {psnr(M, near):.2f} dB, away {psnr(M, ~near):.2f} dB, all {psnr(M, np.ones_like(near)):.2f} dB')
mips = [np.max(M, axis=0) for M in (V, W, B)]
g = 0.6
tiles = [Image.fromarray((np.clip(m, 0, 1) ** g * 255).astype(np.uint8)).convert('RGB') for m in mips]
for t in tiles[1:]:
    d = ImageDraw.Draw(t)
    for f in range(core, nx, core): d.line([(f, 0), (f, ny)], fill=(255, 60, 60), width=1)
    for f in range(core, ny, core): d.line([(0, f), (nx, f)], fill=(255, 60, 60), width=1)
canvas = Image.new('RGB', (3 * nx + 20, ny + 200), 'white')
for i, t in enumerate(tiles): canvas.paste(t, (i * (nx + 10), 0))
d = ImageDraw.Draw(canvas)
for i, label in enumerate(['data (z-MIP)', 'whole fit', 'bricked fit (faces in red)']): d.text((i * (nx + 10) + 5, 5), label, fill=(255, 255, 0))
# profile across the first vertical face, along the row where the MIP crosses it brightest
f = core
row = int(np.argmax(mips[0][:, f]))
xs = np.arange(max(0, f - 40), min(nx, f + 40))
prof = [m[row, xs] for m in mips]
h0 = ny + 20; hh = 160; x0 = 40; w = 3 * nx - 60
d.rectangle([x0, h0, x0 + w, h0 + hh], outline=(0, 0, 0))
colours = [(0, 0, 0), (40, 120, 255), (230, 60, 40)]
for p, c in zip(prof, colours):
    pts = [(x0 + (x - xs[0]) / (xs[-1] - xs[0]) * w, h0 + hh - float(v) * hh) for x, v in zip(xs, p)]
    d.line(pts, fill=c, width=2)
fx = x0 + (f - xs[0]) / (xs[-1] - xs[0]) * w
d.line([(fx, h0), (fx, h0 + hh)], fill=(255, 60, 60), width=1)
d.text((x0 + 5, h0 + 3), f'z-MIP row {row}, x {xs[0]}..{xs[-1]}, brick face at x={f} (red): data black, whole blue, bricked red', fill=(0, 0, 0))
canvas.save(out)
print('wrote', out, 'row', row)
