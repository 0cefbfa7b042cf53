// SPDX-License-Identifier: Apache-2.0
// The hisnegs MIP viewer's logic: decodes the embedded model and cameras, draws each
// Gaussian as an instanced screen-space quad from the EWA projection of
// splat/splat_math.hpp (same Σ2D incl. low_pass, same cutoff q <= δ, value a·exp(−q/2))
// blended with MAX into a float target (a hard MIP, order-free), then maps it for
// display (window, gamma, colour map). Not a soft MIP. Orbit / pan / zoom with mouse
// and touch, a depth slab, a µm scale bar, PNG screenshots at any size, the camera as
// cameras.json, and (served by `hisnegs view --volume`) a swipe comparison with the
// volume's ray-marched MIP from the server, with its PSNR.
//
// Contract (tests rely on it): `#view=N&ui=0` shows view N of the embedded cameras with
// its own intrinsics and size and no UI; document.body.dataset.ready = "1" once drawn.
// `&slab=T&offset=O` sets the depth slab (centre depths within O ± T/2 of the view's
// target, in µm, or world units when the checkpoint has no spacing); `&compare=1&swipe=F`
// turns on the comparison with the volume's MIP (served pages only).
"use strict";
(function () {
  const errorBox = document.getElementById("error");
  function report(message) {
    // One recognisable console line per failure; headless tests scan for it.
    console.error("hisnegs-viewer error: " + message);
    errorBox.textContent = message;
  }
  window.addEventListener("error", (e) => report(e.message || String(e)));

  // --- data ------------------------------------------------------------------------
  // hisnegs-meta: {"count", "model_format": "hgs" | "float32", "floats_per_gaussian": 10,
  //   "cutoff", "low_pass", "um_per_world", "truth", "cameras": cameras.json}
  // hisnegs-model: base64 of the compact .hgs file (docs/file-formats.md), or of
  //   count × 10 little-endian float32. Either becomes `packed`: per Gaussian mean x y z,
  //   Σ xx xy xz yy yz zz (world units²), amplitude a = sigmoid(logit).
  const meta = JSON.parse(document.getElementById("hisnegs-meta").textContent);
  const stride = meta.floats_per_gaussian;
  function base64Bytes(text) {
    const bin = atob(text);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; ++i) bytes[i] = bin.charCodeAt(i);
    return bytes;
  }
  // Σ = (R diag(s)) (R diag(s))ᵀ of the unit quaternion q = (w, x, y, z) and
  // standard deviations s, as gmf/gaussian_math.hpp covariance_from_axes.
  function packGaussian(out, k, mean, s, q, a) {
    const [w, x, y, z] = q;
    const R = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
               2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
               2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)];
    const M = R.map((v, i) => v * s[i % 3]);
    const cov = (r, c) => M[3 * r] * M[3 * c] + M[3 * r + 1] * M[3 * c + 1] + M[3 * r + 2] * M[3 * c + 2];
    out.set([mean[0], mean[1], mean[2], cov(0, 0), cov(0, 1), cov(0, 2), cov(1, 1), cov(1, 2), cov(2, 2), a], k * stride);
  }
  // CRC-32 (the polynomial of zlib, gzip and PNG, reflected: 0xEDB88320) of a Uint8Array.
  function crc32(bytes) {
    let crc = 0xffffffff;
    for (let i = 0; i < bytes.length; ++i) {
      crc ^= bytes[i];
      for (let b = 0; b < 8; ++b) crc = (crc >>> 1) ^ (0xedb88320 & -(crc & 1));
    }
    return (crc ^ 0xffffffff) >>> 0;
  }
  // The compact checkpoint's decoder (gmf/compact_checkpoint.cpp decode_compact_checkpoint).
  function decodeHgs(bytes) {
    const fail = (what) => { throw new Error("model block: " + what); };
    const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    [0x89, 0x48, 0x47, 0x53, 0x0d, 0x0a, 0x1a, 0x0a].forEach((b, i) => { if (bytes[i] !== b) fail("not a compact checkpoint"); });
    const version = dv.getUint32(8, true);
    if (version < 1 || version > 2) fail("compact format version " + version + ", this page reads 1 and 2");
    // Version 2 ends with the CRC-32 of every byte before it.
    const end = version >= 2 ? bytes.length - 4 : bytes.length;
    if (version >= 2 && crc32(bytes.subarray(0, end)) !== dv.getUint32(end, true)) fail("checksum mismatch: the page is damaged");
    const K = Number(dv.getBigUint64(12, true));
    const [P, S, Rb, A] = [bytes[20], bytes[21], bytes[22], bytes[23]];
    const f32 = (at) => dv.getFloat32(at, true);
    const lo = [0, 1, 2].map((d) => f32(24 + 4 * d)), hi = [0, 1, 2].map((d) => f32(36 + 4 * d));
    const slo = [0, 1, 2].map((d) => f32(48 + 4 * d)), shi = [0, 1, 2].map((d) => f32(60 + 4 * d));
    const zAt = 80 + Number(dv.getBigUint64(72, true));
    const Z = Number(dv.getBigUint64(zAt, true));
    if (zAt + 8 + Z !== end) fail("payload size " + Z + " is not the rest of the block");
    const raw = fzstd.decompress(bytes.subarray(zAt + 8, end));
    const planes = (bits) => Math.ceil(bits / 8);
    const pp = planes(3 * P), sp = planes(S), rp = planes(2 + 3 * Rb), ip = planes(A);
    if (raw.length !== K * (pp + 3 * sp + rp + ip)) fail("payload holds " + raw.length + " bytes, not " + K + " Gaussians");
    // Column c's value k: its byte planes, least significant first (a Number: ≤ 48 bits here).
    const column = [0, pp, pp + sp, pp + 2 * sp, pp + 3 * sp, pp + 3 * sp + rp].map((p) => p * K);
    const get = (col, np, k) => { let v = 0; for (let b = np - 1; b >= 0; --b) v = v * 256 + raw[col + b * K + k]; return v; };
    const deq = (c, l, h, m) => (h > l ? l + (h - l) * (c / m) : l);
    // Coordinate d: bits d, d + 3, d + 6, ... of the Morton code. The page's blocks use
    // the default 16 position bits (hisnegs_viewer writes them), so a code has at most
    // 48 bits: an exact Number, split into 24-bit halves for bit operations.
    if (3 * P > 48) fail(P + " position bits: the page reads up to 16");
    const unmorton = (lo24, hi24, d) => {
      let out = 0;
      for (let b = 0; b < P; ++b) {
        const i = 3 * b + d;
        out += (i < 24 ? (lo24 >>> i) & 1 : (hi24 >>> (i - 24)) & 1) * 2 ** b;
      }
      return out;
    };
    const mP = 2 ** P - 1, mS = 2 ** S - 1, mR = 2 ** Rb - 1, mA = 2 ** A - 1;
    const out = new Float32Array(K * stride);
    let code = 0;
    const h = Math.SQRT1_2;
    const mean = [0, 0, 0];
    for (let k = 0; k < K; ++k) {
      code += get(column[0], pp, k);
      const lo24 = code % 16777216, hi24 = Math.floor(code / 16777216);
      for (let d = 0; d < 3; ++d) mean[d] = deq(unmorton(lo24, hi24, d), lo[d], hi[d], mP);
      const s = [0, 1, 2].map((d) => Math.exp(deq(get(column[1 + d], sp, k), slo[d], shi[d], mS)));
      const word = get(column[4], rp, k);
      const largest = Math.floor(word / 2 ** (3 * Rb));
      const q = [0, 0, 0, 0];
      let small2 = 0;
      for (let j = 3, shift = 0; j >= 0; --j) {
        if (j === largest) continue;
        q[j] = deq(Math.floor(word / 2 ** shift) % (mR + 1), -h, h, mR);
        small2 += q[j] * q[j];
        shift += Rb;
      }
      q[largest] = Math.sqrt(Math.max(0, 1 - small2));
      const n = Math.hypot(q[0], q[1], q[2], q[3]);
      const a = Math.min(Math.max(get(column[5], ip, k) / mA, 1e-7), 1 - 1e-7);
      packGaussian(out, k, mean, s, q.map((v) => v / n), a);
    }
    return out;
  }
  const decodeStart = performance.now();
  const packed = (function () {
    const bytes = base64Bytes(document.getElementById("hisnegs-model").textContent.trim());
    if (meta.model_format === "hgs") {
      const out = decodeHgs(bytes);
      if (out.length !== meta.count * stride) throw new Error("model block holds " + out.length / stride + " Gaussians, expected " + meta.count);
      return out;
    }
    if (bytes.length !== meta.count * stride * 4) {
      throw new Error("model holds " + bytes.length + " bytes, expected " + meta.count * stride * 4);
    }
    // Little-endian floats: read through a DataView so a big-endian host would still be right.
    const view = new DataView(bytes.buffer);
    const out = new Float32Array(meta.count * stride);
    for (let i = 0; i < out.length; ++i) out[i] = view.getFloat32(4 * i, true);
    return out;
  })();
  const decodeMs = performance.now() - decodeStart;
  const cams = meta.cameras;

  // --- camera state ------------------------------------------------------------------
  // R: rows of world->camera rotation (OpenCV axes), t: p_cam = R p + t. The camera
  // orbits, pans and zooms about `target` (world), the point it looks at.
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const add = (a, b, s) => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];
  const norm = (v) => { const l = Math.hypot(v[0], v[1], v[2]); return v.map((x) => x / l); };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  let camera = null;
  let target = [0, 0, 0];
  function center(c) {  // C = −Rᵀ t
    const R = c.R, t = c.t;
    return [0, 1, 2].map((i) => -(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]));
  }
  function withCenter(R, C) { return { R, t: R.map((row) => -dot(row, C)) }; }
  function cameraOfView(n) {
    const v = cams.views[n];
    const c = { R: v.R.map((r) => r.slice()), t: v.T.slice() };
    // The target: the point of the optical axis nearest the world origin (the
    // origin itself for orbit views).
    const C = center(c);
    target = add(C, c.R[2], -dot(C, c.R[2]));
    return c;
  }
  // CONVENTIONS "Orbit pose" about `target`: C = target + r (cos e cos φ, cos e sin φ, sin e).
  function orbitCamera(e, phi, r) {
    const C = add(target, [Math.cos(e) * Math.cos(phi), Math.cos(e) * Math.sin(phi), Math.sin(e)], r);
    const z = norm(add(target, C, -1));
    const up = Math.abs(Math.sin(e)) > 0.999 ? [0, 1, 0] : [0, 0, 1];
    const x = norm(cross(z, up));
    return withCenter([x, cross(z, x), z], C);
  }
  function spherical() {
    const d = add(center(camera), target, -1);
    const r = Math.hypot(d[0], d[1], d[2]);
    return { e: Math.asin(Math.max(-1, Math.min(1, d[2] / r))), phi: Math.atan2(d[1], d[0]), r };
  }
  function targetDepth() { return dot(camera.R[2], target) + camera.t[2]; }
  // Moves camera and target by (dx, dy) image pixels at the target's depth.
  function pan(dx, dy) {
    const s = targetDepth();
    const shift = add(camera.R[0].map((v) => v * (-dx * s / K0.fx)), camera.R[1], -dy * s / K0.fy);
    target = add(target, shift, 1);
    camera = withCenter(camera.R, add(center(camera), shift, 1));
  }

  // --- WebGL2 ----------------------------------------------------------------------
  const canvas = document.getElementById("view");
  const W = cams.width, H = cams.height;
  const K0 = { fx: cams.fx, fy: cams.fy, cx: cams.cx, cy: cams.cy };
  canvas.width = W;
  canvas.height = H;
  const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, depth: false, preserveDrawingBuffer: true });
  if (!gl) throw new Error("WebGL2 is not available");
  if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("EXT_color_buffer_float is not available");
  // 32-bit float targets blend only with EXT_float_blend; 16-bit ones always (error < 2^-11 in [0, 1]).
  const float32 = !!gl.getExtension("EXT_float_blend");

  const splatVS = `#version 300 es
precision highp float;
layout(location = 0) in vec2 corner;     // quad corner in {-1, 1}²
layout(location = 1) in vec3 mean;       // μ, world
layout(location = 2) in vec3 covA;       // Σ xx xy xz
layout(location = 3) in vec3 covB;       // Σ yy yz zz
layout(location = 4) in float amp;       // a = sigmoid(logit)
uniform vec3 r0, r1, r2, t;              // rows of R, translation
uniform vec4 K;                          // fx fy cx cy
uniform vec2 clipZ;                      // near far
uniform vec2 size;                       // W H
uniform float cutoff, lowPass;
flat out vec3 conic;
flat out vec2 centre;
flat out float amplitude;
void cull() { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); conic = vec3(0.0); centre = vec2(0.0); amplitude = 0.0; }
void main() {
  vec3 mc = vec3(dot(r0, mean), dot(r1, mean), dot(r2, mean)) + t;
  // Culled by the centre's depth, as splat_math.hpp project_gaussian.
  if (!(mc.z >= clipZ.x && mc.z <= clipZ.y)) { cull(); return; }
  float iz = 1.0 / mc.z;
  // W = J R, J the pinhole Jacobian at μ_cam (Eq. 4).
  vec3 w0 = (K.x * iz) * r0 + (-K.x * mc.x * iz * iz) * r2;
  vec3 w1 = (K.y * iz) * r1 + (-K.y * mc.y * iz * iz) * r2;
  mat3 S = mat3(covA.x, covA.y, covA.z, covA.y, covB.x, covB.y, covA.z, covB.y, covB.z);
  vec3 Sw0 = S * w0, Sw1 = S * w1;
  float a = dot(w0, Sw0) + lowPass, b = dot(w0, Sw1), c = dot(w1, Sw1) + lowPass;
  float det = a * c - b * b;
  if (!(det > 0.0) || !(a > 0.0)) { cull(); return; }
  conic = vec3(c, -b, a) / det;
  centre = vec2(K.x * mc.x * iz + K.z, K.y * mc.y * iz + K.w);
  amplitude = amp;
  // The δ ellipse's bounding box (±sqrt(δ Σxx), ±sqrt(δ Σyy)) plus a pixel; the
  // fragment test q <= δ decides, as the CPU's per-pixel test does.
  vec2 halfExtent = sqrt(cutoff * vec2(a, c)) + 1.0;
  vec2 p = centre + corner * halfExtent;
  // Pixel coordinates (y down) -> NDC (y up): image row 0 is the top row.
  gl_Position = vec4(2.0 * p.x / size.x - 1.0, 1.0 - 2.0 * p.y / size.y, 0.0, 1.0);
}`;
  const splatFS = `#version 300 es
precision highp float;
flat in vec3 conic;
flat in vec2 centre;
flat in float amplitude;
uniform float cutoff, height;
out vec4 value;
void main() {
  // gl_FragCoord is the pixel centre (c + 0.5, row-from-bottom + 0.5); v counts rows from the top.
  vec2 d = vec2(gl_FragCoord.x, height - gl_FragCoord.y) - centre;
  float q = conic.x * d.x * d.x + 2.0 * conic.y * d.x * d.y + conic.z * d.y * d.y;
  if (q > cutoff) discard;
  value = vec4(amplitude * exp(-0.5 * q), 0.0, 0.0, 1.0);
}`;
  // The background's MIP floor (meta.floor; splat/background_floor.cpp): per pixel the
  // chord of its ray through the stack's box in voxels, L, and E[max of c L samples]
  // from the table of E[max of n] at n = 2^(i / perOctave), interpolated in log n.
  const floorFS = `#version 300 es
precision highp float;
uniform vec3 r0, r1, r2, t;              // rows of R, translation
uniform vec4 K;                          // fx fy cx cy
uniform float height;
uniform vec3 aspect, voxel;              // the box's half-extents and voxel size, world units
uniform float perVoxel, perOctave;       // samples per voxel of path; table points per doubling
uniform highp sampler2D table;           // E[max of 2^(i / perOctave)], i = 0 .. N-1: an N x 1 R32F texture
out vec4 value;
void main() {
  vec2 px = vec2(gl_FragCoord.x, height - gl_FragCoord.y);
  vec3 dc = vec3((px.x - K.z) / K.x, (px.y - K.w) / K.y, 1.0);
  vec3 d = normalize(r0 * dc.x + r1 * dc.y + r2 * dc.z);   // Rᵀ d_cam
  vec3 C = -(r0 * t.x + r1 * t.y + r2 * t.z);               // −Rᵀ t
  vec3 safe = mix(d, vec3(1e-20), equal(d, vec3(0.0)));
  vec3 t0 = (-aspect - C) / safe, t1 = (aspect - C) / safe;
  vec3 lo = min(t0, t1), hi = max(t0, t1);
  float tin = max(max(lo.x, lo.y), max(lo.z, 0.0)), tout = min(min(hi.x, hi.y), hi.z);
  if (!(tout > tin)) discard;
  float n = perVoxel * length((tout - tin) * d / voxel);
  int last = textureSize(table, 0).x - 1;
  float x = n <= 1.0 ? 0.0 : min(log2(n) * perOctave, float(last));
  int i = int(floor(x));
  float a = texelFetch(table, ivec2(i, 0), 0).r, b = texelFetch(table, ivec2(min(i + 1, last), 0), 0).r;
  value = vec4(mix(a, b, x - float(i)), 0.0, 0.0, 1.0);
}`;
  // A background that varies by region (meta.floor.regions; splat::RegionFloor): the
  // ray's chord split at the region edges, c L_j samples in region j, and the mean of
  // their maximum, whose CDF is the product of F_j^(c L_j), from the regions' ln F on
  // one grid of values (logCdf, one row per region), summed from the top down.
  const regionFloorFS = `#version 300 es
precision highp float;
precision highp int;
uniform vec3 r0, r1, r2, t;
uniform vec4 K;
uniform float height;
uniform vec3 aspect, voxel;
uniform float perVoxel;
uniform ivec3 cells;                     // regions per axis
uniform highp sampler2D edges;           // 9 x 3: region edges (voxels) of x, y, z
uniform highp sampler2D levels;          // L x 1: the value m_i of grid interval i
uniform highp sampler2D logCdf;          // L x regions: ln F_j(v_i)
out vec4 value;
float edge(int axis, int k) { return texelFetch(edges, ivec2(k, axis), 0).r; }
void main() {
  vec2 px = vec2(gl_FragCoord.x, height - gl_FragCoord.y);
  vec3 dc = vec3((px.x - K.z) / K.x, (px.y - K.w) / K.y, 1.0);
  vec3 d = normalize(r0 * dc.x + r1 * dc.y + r2 * dc.z);
  vec3 C = -(r0 * t.x + r1 * t.y + r2 * t.z);
  vec3 safe = mix(d, vec3(1e-20), equal(d, vec3(0.0)));
  vec3 t0 = (-aspect - C) / safe, t1 = (aspect - C) / safe;
  vec3 lo = min(t0, t1), hi = max(t0, t1);
  float tin = max(max(lo.x, lo.y), max(lo.z, 0.0)), tout = min(min(hi.x, hi.y), hi.z);
  if (!(tout > tin)) discard;
  vec3 u0 = (C + tin * d + aspect) / voxel, u1 = (C + tout * d + aspect) / voxel;
  float len = length(u1 - u0);
  float cuts[26];
  int nc = 0;
  cuts[nc++] = 0.0;
  cuts[nc++] = 1.0;
  for (int a = 0; a < 3; ++a) {
    for (int k = 1; k < cells[a]; ++k) {
      float e = edge(a, k);
      if ((u0[a] - e) * (u1[a] - e) < 0.0) cuts[nc++] = (e - u0[a]) / (u1[a] - u0[a]);
    }
  }
  for (int i = 1; i < nc; ++i) {  // insertion sort of at most 26
    float x = cuts[i];
    int j = i - 1;
    while (j >= 0 && cuts[j] > x) { cuts[j + 1] = cuts[j]; --j; }
    cuts[j + 1] = x;
  }
  int region[25];
  float n[25];
  int ns = 0;
  float total = 0.0;
  for (int i = 0; i + 1 < nc; ++i) {
    float m = perVoxel * (cuts[i + 1] - cuts[i]) * len;
    if (!(m > 0.0)) continue;
    vec3 mid = u0 + 0.5 * (cuts[i] + cuts[i + 1]) * (u1 - u0);
    ivec3 cell = ivec3(0);
    for (int a = 0; a < 3; ++a) {
      for (int k = 1; k < cells[a]; ++k) cell[a] += mid[a] >= edge(a, k) ? 1 : 0;
    }
    region[ns] = cell.x + cells.x * (cell.y + cells.y * cell.z);
    n[ns++] = m;
    total += m;
  }
  if (!(total > 0.0)) discard;
  float scale = total < 1.0 ? 1.0 / total : 1.0;
  int L = textureSize(levels, 0).x;
  float mean = texelFetch(levels, ivec2(L - 1, 0), 0).r;
  float above = mean;
  for (int i = L - 2; i >= 0; --i) {
    float lp = 0.0;
    for (int k = 0; k < ns; ++k) lp += scale * n[k] * texelFetch(logCdf, ivec2(i, region[k]), 0).r;
    if (lp < -40.0) break;
    float here = texelFetch(levels, ivec2(i, 0), 0).r;
    mean -= (above - here) * exp(lp);
    above = here;
  }
  value = vec4(mean, 0.0, 0.0, 1.0);
}`;
  const displayVS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`;
  const displayFS = `#version 300 es
precision highp float;
uniform highp sampler2D mip;
uniform highp sampler2D ref;             // the volume's MIP (image rows top-down), when comparing
uniform float lo, hi, gamma, height;
uniform float swipeX;                    // pixels right of it show ref; >= width: none
uniform int cmap;
out vec4 colour;
vec3 inferno(float x) {  // polynomial fit of matplotlib's inferno (Matt Zucker, CC0)
  const vec3 c0 = vec3(0.0002189403691192265, 0.001651004631001012, -0.01948089843709184);
  const vec3 c1 = vec3(0.1065134194856116, 0.5639564367884091, 3.932712388889277);
  const vec3 c2 = vec3(11.60249308247187, -3.972853965665698, -15.9423941062914);
  const vec3 c3 = vec3(-41.70399613139459, 17.43639888205313, 44.35414519872813);
  const vec3 c4 = vec3(77.162935699427, -33.40235894210092, -81.80730925738993);
  const vec3 c5 = vec3(-71.31942824499214, 32.62606426397723, 73.20951985803202);
  const vec3 c6 = vec3(25.13112622477341, -12.24266895238567, -23.07032500287172);
  return clamp(c0 + x * (c1 + x * (c2 + x * (c3 + x * (c4 + x * (c5 + x * c6))))), 0.0, 1.0);
}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float v = texelFetch(mip, p, 0).r;
  if (gl_FragCoord.x > swipeX) v = texelFetch(ref, ivec2(p.x, int(height) - 1 - p.y), 0).r;
  float x = clamp((v - lo) / (hi - lo), 0.0, 1.0);
  if (gamma != 1.0) x = pow(x, gamma);
  vec3 c = cmap == 1 ? inferno(x) : (cmap == 2 ? vec3(0.0, x, 0.0) : vec3(x));
  if (int(gl_FragCoord.x) == int(swipeX) && swipeX < float(textureSize(mip, 0).x)) c = vec3(1.0, 0.8, 0.0);  // the swipe line
  colour = vec4(c, 1.0);
}`;

  function compile(type, source, name) {
    const s = gl.createShader(type);
    gl.shaderSource(s, source);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
      throw new Error("shader compile error in " + name + ": " + gl.getShaderInfoLog(s));
    }
    return s;
  }
  function program(vs, fs, name) {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, vs, name + " vertex"));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs, name + " fragment"));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("program link error in " + name + ": " + gl.getProgramInfoLog(p));
    const u = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; ++i) {
      const info = gl.getActiveUniform(p, i);
      u[info.name] = gl.getUniformLocation(p, info.name);
    }
    return { p, u };
  }
  const splat = program(splatVS, splatFS, "splat");
  const display = program(displayVS, displayFS, "display");
  const regional = !!(meta.floor && meta.floor.regions);
  const floorPass = meta.floor ? program(displayVS, regional ? regionFloorFS : floorFS, "floor") : null;
  function floatTexture(data, w, h) {  // an R32F texture, nearest
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.R32F, w, h);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, w, h, gl.RED, gl.FLOAT, new Float32Array(data));
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    return tex;
  }
  const floorTable = meta.floor && !regional ? floatTexture(meta.floor.values, meta.floor.values.length, 1) : null;
  const regionTextures = regional ? (function () {
    const g = meta.floor.regions, L = meta.floor.levels.length, edges = new Array(27).fill(0);
    for (let a = 0; a < 3; ++a) g.edges[a].forEach((e, k) => { edges[a * 9 + k] = e; });
    return { edges: floatTexture(edges, 9, 3), levels: floatTexture(meta.floor.levels, L, 1),
             logCdf: floatTexture(meta.floor.log_cdf, L, g.cells[0] * g.cells[1] * g.cells[2]) };
  })() : null;
  let showFloor = !!meta.floor;  // the "background" check box

  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const cornerBuf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, cornerBuf);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
  const instBuf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, instBuf);
  gl.bufferData(gl.ARRAY_BUFFER, packed, gl.STATIC_DRAW);
  const strideBytes = 4 * stride;
  [[1, 3, 0], [2, 3, 12], [3, 3, 24], [4, 1, 36]].forEach(([loc, n, offset]) => {
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, n, gl.FLOAT, false, strideBytes, offset);
    gl.vertexAttribDivisor(loc, 1);
  });
  gl.bindVertexArray(null);

  function texture(format, w, h) {
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texStorage2D(gl.TEXTURE_2D, 1, format, w, h);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    return tex;
  }
  function framebuffer(tex, what) {
    const fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
    if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error(what + " is incomplete");
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    return fb;
  }
  // A hard-MIP float target of w x h (the view's, or a screenshot's).
  function mipTarget(w, h) {
    const tex = texture(float32 ? gl.R32F : gl.R16F, w, h);
    return { tex, fb: framebuffer(tex, "float render target"), w, h };
  }
  let main = mipTarget(W, H);  // the view's target, re-made when the drawing size changes
  // The volume's MIP from the server (R32F, sampled with texelFetch only: no filtering needed).
  const refTex = texture(gl.R32F, W, H);

  const el = (id) => document.getElementById(id);
  const umPerWorld = meta.um_per_world;  // [x, y, z] or null
  // µm per world unit along world direction d (exact for the axis-aligned voxel scale).
  const umAlong = (d) => umPerWorld ? Math.hypot(d[0] * umPerWorld[0], d[1] * umPerWorld[1], d[2] * umPerWorld[2]) : 1;
  function displaySettings() {
    return { lo: parseFloat(el("lo").value), hi: parseFloat(el("hi").value),
             gamma: parseFloat(el("gamma").value), cmap: parseInt(el("cmap").value, 10) };
  }
  // The depth range drawn: everything, or a slab about the target (µm, or world units without spacing).
  function clipRange() {
    const thick = parseFloat(el("slab").value), offset = parseFloat(el("slab-offset").value) || 0;
    if (!(thick > 0)) return [cams.near, cams.far];
    const perWorld = umAlong(camera.R[2]);
    const mid = targetDepth() + offset / perWorld, half = 0.5 * thick / perWorld;
    return [Math.max(cams.near, mid - half), Math.max(cams.near, mid + half)];
  }

  // Pass 1: the hard MIP of the splats into `t` with intrinsics K; pass 2: window, gamma
  // and colour map into `outFb` (null: the canvas), comparing with the volume's MIP
  // right of `swipeX` pixels.
  function render(t, K, outFb, swipeX) {
    const c = camera, clip = clipRange();
    gl.bindFramebuffer(gl.FRAMEBUFFER, t.fb);
    gl.viewport(0, 0, t.w, t.h);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendEquation(gl.MAX);
    gl.blendFunc(gl.ONE, gl.ONE);
    if (floorPass && showFloor) {  // max(splats, floor): MAX blending is order-free
      const f = floorPass.u;
      gl.useProgram(floorPass.p);
      gl.uniform3fv(f.r0, c.R[0]);
      gl.uniform3fv(f.r1, c.R[1]);
      gl.uniform3fv(f.r2, c.R[2]);
      gl.uniform3fv(f.t, c.t);
      gl.uniform4f(f.K, K.fx, K.fy, K.cx, K.cy);
      gl.uniform1f(f.height, t.h);
      gl.uniform3fv(f.aspect, meta.floor.aspect);
      gl.uniform3fv(f.voxel, meta.floor.voxel);
      gl.uniform1f(f.perVoxel, meta.floor.samples_per_voxel);
      if (regional) {
        gl.uniform3iv(f.cells, meta.floor.regions.cells);
        [["edges", regionTextures.edges], ["levels", regionTextures.levels], ["logCdf", regionTextures.logCdf]]
          .forEach(([name, tex], unit) => {
            gl.activeTexture(gl.TEXTURE0 + unit);
            gl.bindTexture(gl.TEXTURE_2D, tex);
            gl.uniform1i(f[name], unit);
          });
        gl.activeTexture(gl.TEXTURE0);
      } else {
        gl.uniform1f(f.perOctave, meta.floor.per_octave);
        gl.activeTexture(gl.TEXTURE0);
        gl.bindTexture(gl.TEXTURE_2D, floorTable);
        gl.uniform1i(f.table, 0);
      }
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
    gl.useProgram(splat.p);
    const u = splat.u;
    gl.uniform3fv(u.r0, c.R[0]);
    gl.uniform3fv(u.r1, c.R[1]);
    gl.uniform3fv(u.r2, c.R[2]);
    gl.uniform3fv(u.t, c.t);
    gl.uniform4f(u.K, K.fx, K.fy, K.cx, K.cy);
    gl.uniform2f(u.clipZ, clip[0], clip[1]);
    gl.uniform2f(u.size, t.w, t.h);
    gl.uniform1f(u.cutoff, meta.cutoff);
    gl.uniform1f(u.lowPass, meta.low_pass);
    gl.uniform1f(u.height, t.h);
    gl.bindVertexArray(vao);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, meta.count);
    gl.bindVertexArray(null);
    gl.disable(gl.BLEND);
    gl.bindFramebuffer(gl.FRAMEBUFFER, outFb);
    gl.viewport(0, 0, t.w, t.h);
    gl.useProgram(display.p);
    const s = displaySettings();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, t.tex);
    gl.uniform1i(display.u.mip, 0);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, refTex);
    gl.uniform1i(display.u.ref, 1);
    gl.uniform1f(display.u.lo, s.lo);
    gl.uniform1f(display.u.hi, s.hi > s.lo ? s.hi : s.lo + 1e-6);
    gl.uniform1f(display.u.gamma, s.gamma > 0 ? s.gamma : 1);
    gl.uniform1f(display.u.height, t.h);
    gl.uniform1f(display.u.swipeX, swipeX);
    gl.uniform1i(display.u.cmap, s.cmap);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  }

  // --- comparison with the volume (hisnegs view --volume) ------------------------------
  let refFor = null;  // the camera key whose volume MIP refTex holds
  let refRequest = 0, refTimer = 0;
  const cameraKey = (c) => "R=" + c.R.flat().join(",") + "&T=" + c.t.join(",");
  const comparing = () => meta.truth && el("compare").checked;
  function requestTruth() {
    clearTimeout(refTimer);
    if (!comparing()) return;
    const key = cameraKey(camera);
    if (key === refFor) return;
    el("psnr").textContent = "rendering the volume's MIP on the server…";
    refTimer = setTimeout(async () => {
      const id = ++refRequest;
      try {
        const res = await fetch("truth?" + key);
        if (!res.ok) throw new Error("/truth: " + res.status + " " + (await res.text()).trim());
        const data = new Float32Array(await res.arrayBuffer());
        if (id !== refRequest) return;  // the camera moved on meanwhile
        if (data.length !== W * H) throw new Error("/truth sent " + data.length + " values, expected " + W * H);
        gl.bindTexture(gl.TEXTURE_2D, refTex);
        gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, W, H, gl.RED, gl.FLOAT, data);
        refFor = key;
        const psnr = parseFloat(res.headers.get("X-Hisnegs-Psnr"));
        const peak = parseFloat(res.headers.get("X-Hisnegs-Truth-Max"));
        el("psnr").textContent = "model (CPU hard MIP) vs volume MIP: " +
            (isFinite(psnr) ? psnr.toFixed(2) + " dB" : "identical (MSE 0)") +
            (peak === 0 ? "; the volume is empty in this view" : "");
        draw();
      } catch (err) {
        report(err.message);
      }
    }, 150);
  }

  // --- drawing, scale bar, stats -------------------------------------------------------------
  // How many canvas pixels one image pixel takes on screen (object-fit: contain).
  function screenScale() {
    const r = canvas.getBoundingClientRect();
    return r.width > 0 ? Math.min(r.width / W, r.height / H) : 1;
  }
  function niceLength(x) {  // the largest 1, 2, 5 × 10^n not above x
    const p = Math.pow(10, Math.floor(Math.log10(x)));
    return [5, 2, 1].map((m) => m * p).find((v) => v <= x) || p;
  }
  function updateScaleBar() {
    const bar = el("scalebar");
    const depth = targetDepth();
    if (!umPerWorld || !(depth > 0)) { bar.hidden = true; return; }
    const pxPerUm = (K0.fx / depth) / umAlong(camera.R[0]) * screenScale();  // screen px per µm at the target
    const um = niceLength(150 / pxPerUm);
    bar.hidden = false;
    el("scalebar-bar").style.width = (um * pxPerUm).toFixed(1) + "px";
    el("scalebar-label").textContent = (um >= 1000 ? um / 1000 + " mm" : um + " µm");
  }
  // The drawing size. With the UI the view fills the window (the camera's aspect kept)
  // and is drawn at its device pixels, the intrinsics scaled as a screenshot's, and at
  // a quarter of the pixels while the user drags or zooms; at the camera's own W x H
  // with #ui=0 (the screenshot contract), with "camera size" ticked, and while
  // comparing with the volume's MIP (the server sends W x H).
  let interacting = false, settleTimer = 0;
  const nativeSize = () => document.body.classList.contains("noui") || el("native").checked || comparing();
  function drawingSize() {
    const noui = document.body.classList.contains("noui");
    const cssW = noui ? W : Math.max(1, Math.min(window.innerWidth, window.innerHeight * W / H));
    const cssH = noui ? H : cssW * H / W;
    canvas.style.width = cssW + "px";
    canvas.style.height = cssH + "px";
    if (nativeSize()) return { w: W, h: H };
    const max = gl.getParameter(gl.MAX_RENDERBUFFER_SIZE);
    const scale = (window.devicePixelRatio || 1) * (interacting ? 0.5 : 1);
    return { w: Math.max(1, Math.min(max, Math.round(cssW * scale))), h: Math.max(1, Math.min(max, Math.round(cssH * scale))) };
  }
  // Ends the reduced drawing 150 ms after the last wheel step or at the last pointer's lift.
  function settle(now) {
    clearTimeout(settleTimer);
    if (now) { if (interacting) { interacting = false; draw(); } return; }
    settleTimer = setTimeout(() => settle(true), 150);
  }
  function draw() {
    const t0 = performance.now();
    const size = drawingSize();
    if (size.w !== main.w || size.h !== main.h) {
      gl.deleteTexture(main.tex);
      gl.deleteFramebuffer(main.fb);
      main = mipTarget(size.w, size.h);
      canvas.width = size.w;
      canvas.height = size.h;
    }
    const K = { fx: K0.fx * size.w / W, fy: K0.fy * size.h / H, cx: K0.cx * size.w / W, cy: K0.cy * size.h / H };
    const showRef = comparing() && refFor === cameraKey(camera);
    render(main, K, null, showRef ? parseFloat(el("swipe").value) * size.w : size.w + 1);
    gl.finish();
    const ms = performance.now() - t0;
    el("stats").textContent = meta.count + " Gaussians, drawn at " + size.w + "×" + size.h +
                              (size.w === W && size.h === H ? " (the camera's size)" : " (camera " + W + "×" + H + ")") +
                              (interacting ? ", reduced while moving" : "") + ", " + ms.toFixed(1) + " ms/frame (" +
                              (float32 ? "32" : "16") + "-bit float target)" +
                              (umPerWorld ? "" : "; no spacing in the checkpoint: no scale bar, slab in world units");
    updateScaleBar();
    el("camera-json").value = cameraJson();
    requestTruth();
  }

  // --- screenshot and camera ---------------------------------------------------------------
  // The current view at w x h: the intrinsics scaled with the image (same field of view).
  function screenshot(w, h) {
    const max = Math.min(gl.getParameter(gl.MAX_TEXTURE_SIZE), gl.getParameter(gl.MAX_RENDERBUFFER_SIZE));
    if (!(w >= 1 && h >= 1 && w <= max && h <= max)) throw new Error("screenshot size " + w + "×" + h + ": each side must be in 1.." + max);
    const K = { fx: K0.fx * w / W, fy: K0.fy * h / H, cx: K0.cx * w / W, cy: K0.cy * h / H };
    const t = mipTarget(w, h);
    const rgbaTex = texture(gl.RGBA8, w, h);
    const rgbaFb = framebuffer(rgbaTex, "screenshot target");
    try {
      render(t, K, rgbaFb, w + 1);
      const pixels = new Uint8ClampedArray(w * h * 4);
      gl.bindFramebuffer(gl.FRAMEBUFFER, rgbaFb);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      const flipped = new Uint8ClampedArray(w * h * 4);  // GL rows are bottom-up
      for (let y = 0; y < h; ++y) flipped.set(pixels.subarray((h - 1 - y) * w * 4, (h - y) * w * 4), y * w * 4);
      const c2 = document.createElement("canvas");
      c2.width = w;
      c2.height = h;
      c2.getContext("2d").putImageData(new ImageData(flipped, w, h), 0, 0);
      return c2;
    } finally {
      [t.tex, rgbaTex].forEach((x) => gl.deleteTexture(x));
      [t.fb, rgbaFb].forEach((x) => gl.deleteFramebuffer(x));
    }
  }
  function saveScreenshot() {
    const w = parseInt(el("shot-w").value, 10), h = parseInt(el("shot-h").value, 10);
    screenshot(w, h).toBlob((blob) => {
      const a = document.createElement("a");
      a.href = URL.createObjectURL(blob);
      a.download = "hisnegs_view_" + w + "x" + h + ".png";
      a.click();
      setTimeout(() => URL.revokeObjectURL(a.href), 1000);
    }, "image/png");
  }
  // The current camera as a cameras.json (CONVENTIONS) of one view.
  function cameraJson() {
    const out = { width: W, height: H, fx: K0.fx, fy: K0.fy, cx: K0.cx, cy: K0.cy, near: cams.near, far: cams.far,
                  views: [{ name: "viewer", R: camera.R.map((r) => r.slice()), T: camera.t.slice() }] };
    return JSON.stringify(out, null, 1);
  }
  function copyCamera() {
    const text = el("camera-json");
    text.value = cameraJson();
    text.select();
    if (navigator.clipboard && window.isSecureContext) {
      navigator.clipboard.writeText(text.value).catch(() => document.execCommand("copy"));
    } else {
      document.execCommand("copy");
    }
  }

  // --- views, hash, UI ---------------------------------------------------------------
  const select = el("view-select");
  cams.views.forEach((v, i) => {
    const o = document.createElement("option");
    o.value = String(i);
    o.textContent = i + ": " + v.name;
    select.appendChild(o);
  });
  function parseHash() {
    const params = new URLSearchParams(location.hash.replace(/^#/, ""));
    const view = params.has("view") ? parseInt(params.get("view"), 10) : 0;
    if (!(view >= 0 && view < cams.views.length)) throw new Error("#view=" + params.get("view") + ": expected 0.." + (cams.views.length - 1));
    return { view, ui: params.get("ui") !== "0", params };
  }
  function applyHash() {
    const h = parseHash();
    // #slab=T&offset=O: the depth slab of the UI (µm; world units without spacing).
    [["slab", "slab"], ["offset", "slab-offset"]].forEach(([key, id]) => {
      if (!h.params.has(key)) return;
      const v = parseFloat(h.params.get(key));
      if (!isFinite(v)) throw new Error("#" + key + "=" + h.params.get(key) + ": expected a number");
      el(id).value = String(v);
    });
    // #background=0: the Gaussians alone (a model with a recorded background draws its floor).
    if (h.params.has("background")) el("background").checked = h.params.get("background") !== "0";
    showFloor = !!meta.floor && el("background").checked;
    // #native=1: draw at the camera's own W x H (stretched to the window) rather than the window's pixels.
    if (h.params.has("native")) el("native").checked = h.params.get("native") === "1";
    // #compare=1&swipe=F: the comparison with the volume's MIP (hisnegs view --volume).
    if (h.params.has("compare")) el("compare").checked = h.params.get("compare") === "1";
    if (h.params.has("swipe")) el("swipe").value = h.params.get("swipe");
    document.body.classList.toggle("noui", !h.ui);
    select.value = String(h.view);
    camera = cameraOfView(h.view);
    draw();
  }
  el("shot-w").value = String(W);
  el("shot-h").value = String(H);
  el("slab-unit").textContent = umPerWorld ? "µm" : "world units";
  el("compare-box").hidden = !meta.truth;
  el("background-box").hidden = !meta.floor;
  el("background").addEventListener("input", () => { showFloor = !!meta.floor && el("background").checked; draw(); });
  window.addEventListener("hashchange", applyHash);
  window.addEventListener("resize", draw);  // a new window size: a new drawing size (and scale bar)
  select.addEventListener("change", () => { camera = cameraOfView(parseInt(select.value, 10)); draw(); });
  el("reset").addEventListener("click", () => { camera = cameraOfView(parseInt(select.value, 10)); draw(); });
  ["lo", "hi", "gamma", "cmap", "slab", "slab-offset", "compare", "swipe", "native"].forEach((id) => el(id).addEventListener("input", draw));
  el("shot").addEventListener("click", () => { try { saveScreenshot(); } catch (err) { report(err.message); } });
  el("camera-copy").addEventListener("click", copyCamera);

  // Mouse and touch: one pointer orbits about the target (shift, right or middle button:
  // pans); two pointers pinch-zoom and pan with their midpoint; the wheel zooms.
  const pointers = new Map();
  let gesture = null;
  function startGesture(ev) {
    const pts = [...pointers.values()];
    const mid = pts.reduce((m, p) => [m[0] + p.x / pts.length, m[1] + p.y / pts.length], [0, 0]);
    const spread = pts.length > 1 ? Math.hypot(pts[0].x - pts[1].x, pts[0].y - pts[1].y) : 0;
    gesture = { n: pts.length, mid, spread, s: spherical(),
                pan: pts.length === 1 && (ev.shiftKey || ev.button === 1 || ev.button === 2) };
  }
  canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
  canvas.addEventListener("pointerdown", (ev) => {
    pointers.set(ev.pointerId, { x: ev.clientX, y: ev.clientY });
    canvas.setPointerCapture(ev.pointerId);
    startGesture(ev);
  });
  const lift = (ev) => {
    pointers.delete(ev.pointerId);
    if (pointers.size > 0) {
      startGesture(ev);
    } else {
      gesture = null;
      settle(true);
    }
  };
  canvas.addEventListener("pointerup", lift);
  canvas.addEventListener("pointercancel", lift);
  canvas.addEventListener("pointermove", (ev) => {
    if (!gesture || !pointers.has(ev.pointerId)) return;
    pointers.set(ev.pointerId, { x: ev.clientX, y: ev.clientY });
    const pts = [...pointers.values()];
    const mid = pts.reduce((m, p) => [m[0] + p.x / pts.length, m[1] + p.y / pts.length], [0, 0]);
    const scale = screenScale();
    const dx = (mid[0] - gesture.mid[0]) / scale, dy = (mid[1] - gesture.mid[1]) / scale;  // image pixels
    if (gesture.n >= 2 && pts.length >= 2) {
      const spread = Math.hypot(pts[0].x - pts[1].x, pts[0].y - pts[1].y);
      camera = orbitCamera(gesture.s.e, gesture.s.phi, gesture.s.r * gesture.spread / Math.max(spread, 1));
      pan(dx, dy);
      gesture.mid = mid;
      gesture.spread = spread;
      gesture.s = spherical();
    } else if (gesture.pan) {
      pan(dx, dy);
      gesture.mid = mid;
    } else {
      const k = Math.PI / 360;  // 0.5° per screen pixel
      const e = Math.max(-1.55, Math.min(1.55, gesture.s.e + (mid[1] - gesture.mid[1]) * k));
      camera = orbitCamera(e, gesture.s.phi - (mid[0] - gesture.mid[0]) * k, gesture.s.r);
    }
    interacting = true;
    draw();
  });
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const s = spherical();
    camera = orbitCamera(s.e, s.phi, s.r * Math.exp(ev.deltaY * 0.001));
    interacting = true;
    draw();
    settle(false);
  }, { passive: false });

  // For scripts and tests: the current camera, a screenshot of any size as a data URL.
  window.hisnegsViewer = {
    camera: () => JSON.parse(cameraJson()),
    screenshot: (w, h) => screenshot(w, h).toDataURL("image/png"),
  };

  applyHash();
  // #bench=N: N more frames of the same view, timed to a readPixels that waits for each (real time only when
  // the browser runs without a virtual time budget), logged as one console line.
  const benchFrames = parseInt(new URLSearchParams(location.hash.replace(/^#/, "")).get("bench") || "0", 10);
  if (benchFrames > 0) {
    const t0 = performance.now();
    const pixel = new Uint8Array(4);
    for (let i = 0; i < benchFrames; ++i) {
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);  // waits for the frame, unlike finish()
    }
    console.log("hisnegs-viewer bench: " + ((performance.now() - t0) / benchFrames).toFixed(2) + " ms/frame over " +
                benchFrames + " frames, " + meta.count + " Gaussians, " + main.w + "x" + main.h +
                " (window " + window.innerWidth + "x" + window.innerHeight + ", device pixel ratio " +
                (window.devicePixelRatio || 1) + ")");
  }
  document.body.dataset.ready = "1";
  // The same signal for tools that read the console rather than the DOM.
  console.log("hisnegs-viewer ready: view " + select.value + " drawn; " + meta.model_format + " model of " + meta.count +
              " Gaussians decoded in " + decodeMs.toFixed(1) + " ms");
})();
