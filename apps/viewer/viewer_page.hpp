// SPDX-License-Identifier: Apache-2.0
// The WebGL2 hard-MIP viewer page (apps/viewer/viewer.html + viewer.js, embedded at
// build time) and the one self-contained HTML file a model and cameras make of it
// (`hisnegs export html`). The projection itself lives in viewer.js; not a server.
#pragma once

#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "splat/background_floor.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {

// Floats per Gaussian in the page's model block: mean x y z (world), Σ xx xy xz yy yz zz
// (world units²), amplitude a = sigmoid(logit).
inline constexpr int kViewerFloatsPerGaussian = 10;

// How the page holds the model: the compact .hgs file (gmf/core/compact_checkpoint.hpp,
// default bit depths; decoded by the page with the vendored fzstd; within the
// format's bounds, ~0.005 dB from float32 on op1) or exact float32 parameters
// (kViewerFloatsPerGaussian per Gaussian, about three times larger).
enum class ViewerModelBlock { kCompact, kFloat32 };

// What the page renders with besides the model and cameras (the CPU renderer's
// SplatOptions of the same names, so the page draws what `render --mode hard` does).
struct ViewerPageSettings {
  double cutoff = 16.0;   // δ: a Gaussian touches the pixels with q <= δ, > 0
  double low_pass = 0.0;  // pixels², added to Σ2D's diagonal, >= 0
  // µm per world unit along x, y, z (the scale bar); none: no scale bar.
  std::optional<std::array<double, 3>> um_per_world;
  bool truth = false;  // the page may ask its server for /truth (hisnegs view --volume)
  ViewerModelBlock model_block = ViewerModelBlock::kCompact;
  // The model's background floor (splat/background_floor.hpp), drawn by the page as
  // the CPU renderer draws it (a check box and #background=0 hide it); none: none().
  splat::BackgroundFloors floor;
};

// µm per world unit along x, y, z from the checkpoint's volume shape, spacing and
// aspect (CONVENTIONS: a voxel is 2 a / N world units); empty when any is missing.
[[nodiscard]] std::optional<std::array<double, 3>> um_per_world(const gmf::CheckpointMeta& meta);

// The page template (with its <!--HISNEGS_DATA--> marker) and script, as embedded.
[[nodiscard]] std::string_view viewer_page_template();
[[nodiscard]] std::string_view viewer_script();
[[nodiscard]] std::string_view viewer_zstd_script();  // vendor/fzstd-*.umd.js

// The model block of the page: size() = kViewerFloatsPerGaussian × mixture.size()
// (Σ computed in double from log-scales and the normalized quaternion, then rounded).
[[nodiscard]] std::vector<float> pack_viewer_model(const gmf::GaussianMixture& mixture);

// RFC 4648 base64 of `bytes` (with padding).
[[nodiscard]] std::string base64_encode(const void* bytes, std::size_t size);

// The self-contained page: template + meta JSON (count, model_format "hgs" or
// "float32", cutoff, low_pass, um_per_world, truth, cameras as cameras.json) + base64
// of the model block (the .hgs file, or little-endian float32) + the scripts (fzstd,
// viewer.js).
// Opens from file:// with no server. Throws std::invalid_argument for settings out of
// range or a camera set with no views.
// `model_block_bytes`, if given, gets the size of the model block before base64.
[[nodiscard]] std::string viewer_html(const gmf::GaussianMixture& mixture, const splat::CameraSet& cameras,
                                      const ViewerPageSettings& settings, std::size_t* model_block_bytes = nullptr);

}  // namespace hisnegs::apps
