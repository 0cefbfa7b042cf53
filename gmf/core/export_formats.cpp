// SPDX-License-Identifier: Apache-2.0
// Splat-viewer PLY rows and dense resampling of a mixture (on gmf/rasterize's rasterizer).
#include "gmf/core/export_formats.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

#include "gmf/core/rasterize.hpp"

namespace hisnegs::gmf {

std::string_view to_string(SplatColormap colormap) {
  switch (colormap) {
    case SplatColormap::kGrey:
      return "grey";
    case SplatColormap::kFire:
      return "fire";
  }
  return "?";
}

std::array<double, 3> splat_color(double a, SplatColormap colormap) {
  const auto unit = [](double v) { return std::clamp(v, 0.0, 1.0); };
  switch (colormap) {
    case SplatColormap::kGrey:
      return {unit(a), unit(a), unit(a)};
    case SplatColormap::kFire:
      return {unit(3.0 * a), unit(3.0 * a - 1.0), unit(3.0 * a - 2.0)};
  }
  throw std::logic_error("invalid SplatColormap");
}

io::PlyTable splat_ply_table(const GaussianMixture& mixture, const SplatPlyOptions& options) {
  constexpr int kShRest = 45;  // 3 colours × 15 coefficients of SH degrees 1..3
  std::vector<std::string> names = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  if (options.sh_rest) {
    for (int i = 0; i < kShRest; ++i) names.push_back("f_rest_" + std::to_string(i));
  }
  for (const char* n : {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"}) {
    names.emplace_back(n);
  }
  std::vector<io::PlyProperty> props;
  props.reserve(names.size());
  for (std::string& n : names) props.push_back({std::move(n), io::PlyType::kFloat32});
  const std::size_t columns = props.size();
  io::PlyElement vertex("vertex", static_cast<std::int64_t>(mixture.size()), std::move(props));

  std::vector<float> row(columns, 0.0f);  // normals and f_rest stay 0
  std::byte* out = vertex.bytes().data();
  for (std::size_t k = 0; k < mixture.size(); ++k) {
    const GaussianParams& g = mixture[k];
    for (float v : to_array(g)) {
      if (!std::isfinite(v))
        throw std::invalid_argument("gaussian " + std::to_string(k) + " has a non-finite parameter");
    }
    std::size_t c = 0;
    for (float v : g.mean) row[c++] = v;
    c += 3;  // nx ny nz
    const std::array<double, 3> rgb = splat_color(intensity<double>(g), options.colormap);
    for (double v : rgb) row[c++] = static_cast<float>((v - 0.5) / kShC0);
    if (options.sh_rest) c += kShRest;
    row[c++] = g.intensity_logit;
    for (float v : g.log_scale) row[c++] = v;
    for (float v : g.rotation) row[c++] = v;
    std::memcpy(out + k * vertex.row_size(), row.data(), vertex.row_size());
  }

  io::PlyTable table;
  table.comments = {"hisnegs splat_ply: a visual aid for 3D Gaussian-splatting viewers (alpha-blended, not a MIP)",
                    "hisnegs splat_ply: opacity = intensity logit, f_dc = " + std::string(to_string(options.colormap)) +
                        " colour of sigmoid(opacity), scale = log sigma, rot = w x y z; world units of the model"};
  table.elements.push_back(std::move(vertex));
  return table;
}

void write_splat_ply(const std::filesystem::path& path, const GaussianMixture& mixture,
                     const SplatPlyOptions& options) {
  io::PlyTable table;
  try {
    table = splat_ply_table(mixture, options);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path.string() + ": cannot write splat PLY: " + e.what());
  }
  io::write_ply(path, table);
}

std::vector<float> rasterize_dense(const GaussianMixture& mixture, const MixtureModel& model,
                                   const io::WorldFrame& frame, double tail, bool untruncated_sum) {
  if (!(tail > 0.0)) throw std::invalid_argument("rasterize_dense: tail must be > 0");
  return rasterize_mixture(mixture, frame, RasterizeOptions::exported(model, tail, untruncated_sum));
}

}  // namespace hisnegs::gmf
