// SPDX-License-Identifier: Apache-2.0
// Assembles the self-contained viewer page from the embedded template and script,
// the packed model (base64) and the cameras (JSON). No rendering here.
#include "apps/viewer/viewer_page.hpp"

#include <bit>
#include <cmath>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "apps/viewer/viewer_assets.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "io/volume.hpp"

namespace hisnegs::apps {
namespace {

constexpr std::string_view kDataMarker = "<!--HISNEGS_DATA-->";

// JSON text safe inside a <script> element: "</" cannot close it.
std::string script_safe(std::string json) {
  for (std::size_t at = 0; (at = json.find("</", at)) != std::string::npos; at += 3) json.replace(at, 2, "<\\/");
  return json;
}

// The page's meta.floor: the box, and either the table of E[max of n] (one
// background for the stack) or the regions' CDFs (splat::RegionFloor), which the
// page's floor shaders evaluate as the renderer does.
nlohmann::ordered_json floor_json(const splat::BackgroundFloors& floor) {
  const io::WorldFrame& frame = floor.frame();
  const Eigen::Vector3d& a = frame.aspect();
  const Eigen::Vector3d& v = frame.voxel_size();
  nlohmann::ordered_json j = {{"aspect", {a.x(), a.y(), a.z()}}, {"voxel", {v.x(), v.y(), v.z()}}};
  if (!floor.regional()) {
    const splat::FloorTable& table = floor.table();
    j["samples_per_voxel"] = table.samples_per_voxel();
    j["per_octave"] = splat::FloorTable::points_per_octave();
    j["values"] = table.values();
    return j;
  }
  const splat::RegionFloor& r = floor.regional_floor();
  const gmf::BackgroundRegions& g = r.regions();
  j["samples_per_voxel"] = r.samples_per_voxel();
  j["regions"] = {{"shape", g.shape}, {"cells", g.cells}};
  std::vector<std::vector<int>> edges(3);
  for (int axis = 0; axis < 3; ++axis) {
    for (int k = 0; k <= g.cells[axis]; ++k) edges[static_cast<std::size_t>(axis)].push_back(g.edge(axis, k));
  }
  j["regions"]["edges"] = edges;
  j["levels"] = r.levels();
  j["log_cdf"] = r.log_cdf();
  return j;
}

}  // namespace

std::string_view viewer_page_template() {
  return {reinterpret_cast<const char*>(detail::kViewerHtml), detail::kViewerHtmlSize};
}

std::string_view viewer_script() { return {reinterpret_cast<const char*>(detail::kViewerJs), detail::kViewerJsSize}; }

std::string_view viewer_zstd_script() {
  return {reinterpret_cast<const char*>(detail::kViewerZstdJs), detail::kViewerZstdJsSize};
}

std::optional<std::array<double, 3>> um_per_world(const gmf::CheckpointMeta& meta) {
  if (!meta.volume_shape_zyx || !meta.spacing_um || !meta.aspect) return std::nullopt;
  const auto& zyx = *meta.volume_shape_zyx;
  const auto& aspect = *meta.aspect;
  const io::WorldFrame frame(zyx[2], zyx[1], zyx[0], Eigen::Vector3d(aspect[0], aspect[1], aspect[2]));
  std::array<double, 3> out{};
  for (int a = 0; a < 3; ++a) out[a] = (*meta.spacing_um)[a] / frame.voxel_size()[a];
  return out;
}

std::vector<float> pack_viewer_model(const gmf::GaussianMixture& mixture) {
  std::vector<float> out;
  out.reserve(kViewerFloatsPerGaussian * mixture.size());
  for (const gmf::GaussianParams& g : mixture) {
    const Eigen::Matrix3d sigma = gmf::covariance<double>(g);
    for (float m : g.mean) out.push_back(m);
    for (const auto& [r, c] : {std::pair{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}}) {
      out.push_back(static_cast<float>(sigma(r, c)));
    }
    out.push_back(gmf::intensity<float>(g));
  }
  return out;
}

std::string base64_encode(const void* bytes, std::size_t size) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* p = static_cast<const unsigned char*>(bytes);
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 3 <= size; i += 3) {
    const unsigned v = (p[i] << 16) | (p[i + 1] << 8) | p[i + 2];
    for (int s = 18; s >= 0; s -= 6) out.push_back(kAlphabet[(v >> s) & 63]);
  }
  if (const std::size_t rest = size - i; rest > 0) {
    const unsigned v = (p[i] << 16) | (rest == 2 ? p[i + 1] << 8 : 0);
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(rest == 2 ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

std::string viewer_html(const gmf::GaussianMixture& mixture, const splat::CameraSet& cameras,
                        const ViewerPageSettings& settings, std::size_t* model_block_bytes) {
  if (!(std::isfinite(settings.cutoff) && settings.cutoff > 0.0)) {
    throw std::invalid_argument("viewer: cutoff must be a finite number > 0");
  }
  if (!(std::isfinite(settings.low_pass) && settings.low_pass >= 0.0)) {
    throw std::invalid_argument("viewer: low_pass must be a finite number >= 0");
  }
  if (cameras.views.empty()) throw std::invalid_argument("viewer: the camera set has no views");
  static_assert(std::endian::native == std::endian::little, "the page's model block is little-endian");
  const bool compact = settings.model_block == ViewerModelBlock::kCompact;
  std::string block;
  if (compact) {
    block = gmf::encode_compact_checkpoint(mixture, gmf::CheckpointMeta{});
  } else {
    const std::vector<float> packed = pack_viewer_model(mixture);
    block.assign(reinterpret_cast<const char*>(packed.data()), packed.size() * sizeof(float));
  }

  if (model_block_bytes) *model_block_bytes = block.size();
  nlohmann::ordered_json meta;
  meta["count"] = mixture.size();
  meta["model_format"] = compact ? "hgs" : "float32";
  meta["floats_per_gaussian"] = kViewerFloatsPerGaussian;
  meta["cutoff"] = settings.cutoff;
  meta["low_pass"] = settings.low_pass;
  meta["um_per_world"] =
      settings.um_per_world ? nlohmann::ordered_json(*settings.um_per_world) : nlohmann::ordered_json();
  meta["truth"] = settings.truth;
  if (settings.floor.none()) {
    meta["floor"] = nullptr;
  } else {
    meta["floor"] = floor_json(settings.floor);
  }
  meta["cameras"] = nlohmann::ordered_json::parse(splat::cameras_json_text(cameras));

  std::string data;
  data += "<script id=\"hisnegs-meta\" type=\"application/json\">";
  data += script_safe(meta.dump());
  data += "</script>\n<script id=\"hisnegs-model\" type=\"application/octet-stream\">";
  data += base64_encode(block.data(), block.size());
  data += "</script>\n<script>\n";
  data += viewer_zstd_script();
  data += "\n;\n";
  data += viewer_script();
  data += "</script>";

  const std::string_view page = viewer_page_template();
  const std::size_t at = page.find(kDataMarker);
  if (at == std::string_view::npos) throw std::logic_error("viewer.html lacks its <!--HISNEGS_DATA--> marker");
  std::string html;
  html.reserve(page.size() + data.size());
  html.append(page.substr(0, at)).append(data).append(page.substr(at + kDataMarker.size()));
  return html;
}

}  // namespace hisnegs::apps
