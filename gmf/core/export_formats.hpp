// SPDX-License-Identifier: Apache-2.0
// Checkpoint -> files for other tools: a PLY that 3D Gaussian-splatting viewers open
// (`hisnegs export splat-ply`, a visual aid: viewers alpha-blend, they do not take a
// MIP) and the mixture resampled onto a dense voxel grid (`hisnegs export volume`).
// The OpenVDB export is gmf/export_vdb.hpp; writing TIFF stacks is io's.
#pragma once

#include <array>
#include <filesystem>
#include <string_view>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "io/ply.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// 0th-order spherical-harmonics constant of the 3DGS viewers: colour = 0.5 + kShC0 f_dc.
inline constexpr double kShC0 = 0.28209479177387814;

// How a Gaussian's intensity a = sigmoid(ℓ) becomes its viewer colour.
enum class SplatColormap {
  kGrey,  // (a, a, a)
  kFire,  // black -> red -> yellow -> white: (3a, 3a - 1, 3a - 2) clamped to [0, 1]
};
[[nodiscard]] std::string_view to_string(SplatColormap colormap);

struct SplatPlyOptions {
  SplatColormap colormap = SplatColormap::kGrey;  // intensity -> DC colour
  // Also write f_rest_0..f_rest_44 (all 0): the SH-degree-3 layout of the reference
  // 3DGS code, for viewers that read only that layout (SIBR). Web viewers do not need it.
  bool sh_rest = false;
};

// The viewer colour (r, g, b) in [0, 1] of intensity a in [0, 1].
[[nodiscard]] std::array<double, 3> splat_color(double a, SplatColormap colormap);

// One `vertex` element in the reference 3DGS order, all float: x y z nx ny nz
// (normals 0) f_dc_0 f_dc_1 f_dc_2 [f_rest_0..44] opacity scale_0 scale_1 scale_2
// rot_0 rot_1 rot_2 rot_3. The Gaussian maps onto it unchanged where the meaning
// agrees: x y z = μ, scale_i = log-scales, rot_i = q (w x y z), opacity = the
// intensity logit ℓ (viewers take sigmoid(opacity) as alpha, we take sigmoid(ℓ) as
// a); f_dc_i = (c_i - 0.5) / kShC0 with c = splat_color(a). A header comment says
// what the file is. Throws std::invalid_argument for a non-finite parameter.
[[nodiscard]] io::PlyTable splat_ply_table(const GaussianMixture& mixture, const SplatPlyOptions& options);

// Writes splat_ply_table atomically as binary little-endian PLY.
void write_splat_ply(const std::filesystem::path& path, const GaussianMixture& mixture, const SplatPlyOptions& options);

// The model's own f (`model`: its aggregation, β and support δ; model_of(checkpoint.meta,
// δ)) at every voxel centre of `frame`, x fastest like io::Volume (float32), through
// gmf::rasterize_mixture with RasterizeOptions::exported: every term inside its
// support with a_k exp(-m/2) >= tail is included, so a sum is below the fitted f by
// at most tail × (Gaussians reaching the voxel). `tail` > 0, the same meaning as
// VdbExportOptions::tail; `untruncated_sum` as VdbExportOptions'. Memory: 4 bytes
// per voxel of the frame.
[[nodiscard]] std::vector<float> rasterize_dense(const GaussianMixture& mixture, const MixtureModel& model,
                                                 const io::WorldFrame& frame, double tail,
                                                 bool untruncated_sum = false);

}  // namespace hisnegs::gmf
