// SPDX-License-Identifier: Apache-2.0
// Checkpoint <-> PLY table mapping (parameters, `comment hisnegs` metadata) and
// save on top of io::write_ply (load_checkpoint, which reads the PLY and the compact
// format alike, is gmf/core/load_checkpoint.cpp). No PLY parsing here.
#include "gmf/core/checkpoint.hpp"

#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <string_view>

#include "io/error.hpp"

namespace hisnegs::gmf {
namespace fs = std::filesystem;

namespace {

constexpr std::string_view kPrefix = "hisnegs";
constexpr std::string_view kVertex = "vertex";
constexpr std::string_view kFormatVersion = "format_version";
constexpr std::string_view kVolumeShape = "volume_shape";
constexpr std::string_view kSpacing = "spacing_um";
constexpr std::string_view kAspect = "aspect";
constexpr std::string_view kNormalization = "normalization";
constexpr std::string_view kAggregation = "aggregation";
constexpr std::array<std::string_view, 6> kKnownKeys = {kFormatVersion, kVolumeShape,   kSpacing,
                                                        kAspect,        kNormalization, kAggregation};

bool is_known_key(std::string_view key) {
  for (std::string_view k : kKnownKeys) {
    if (k == key) return true;
  }
  return false;
}

bool is_blank(char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; }

bool is_token(std::string_view s) {
  if (s.empty()) return false;
  for (char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if (u <= 0x20 || u == 0x7f) return false;
  }
  return true;
}

bool has_line_break(std::string_view s) { return s.find_first_of("\r\n") != std::string_view::npos; }

// "nan", "inf", "-inf" or the shortest decimal that reads back to the same double.
std::string format_number(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, res.ptr);
}

std::vector<std::string_view> split_ws(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && is_blank(s[i])) ++i;
    const std::size_t start = i;
    while (i < s.size() && !is_blank(s[i])) ++i;
    if (i > start) out.push_back(s.substr(start, i - start));
  }
  return out;
}

template <class T>
bool parse_number(std::string_view token, T& out) {
  const char* end = token.data() + token.size();
  const auto res = std::from_chars(token.data(), end, out);
  return res.ec == std::errc{} && res.ptr == end;
}

// ----- writing -----

void check_positive3(std::string_view key, const std::array<double, 3>& v) {
  for (double x : v) {
    if (!std::isfinite(x) || !(x > 0.0)) {
      throw std::invalid_argument("checkpoint metadata " + std::string(key) + ": " + format_number(x) +
                                  " is not a finite positive number");
    }
  }
}

std::string join3(const std::array<double, 3>& v) {
  return format_number(v[0]) + " " + format_number(v[1]) + " " + format_number(v[2]);
}

std::string comment(std::string_view key, const std::string& value) {
  std::string c = std::string(kPrefix) + " " + std::string(key);
  if (!value.empty()) c += " " + value;
  return c;
}

std::vector<std::string> meta_comments(const CheckpointMeta& meta) {
  if (meta.format_version != kCheckpointFormatVersion) {
    throw std::invalid_argument("checkpoint metadata format_version " + std::to_string(meta.format_version) +
                                ": this build writes only version " + std::to_string(kCheckpointFormatVersion));
  }
  std::vector<std::string> out;
  out.push_back(comment(kFormatVersion, std::to_string(meta.format_version)));
  if (meta.volume_shape_zyx) {
    const auto& s = *meta.volume_shape_zyx;
    for (int n : s) {
      if (n <= 0) {
        throw std::invalid_argument("checkpoint metadata volume_shape: " + std::to_string(n) +
                                    " is not a positive size");
      }
    }
    out.push_back(
        comment(kVolumeShape, std::to_string(s[0]) + " " + std::to_string(s[1]) + " " + std::to_string(s[2])));
  }
  if (meta.spacing_um) {
    check_positive3(kSpacing, *meta.spacing_um);
    out.push_back(comment(kSpacing, join3(*meta.spacing_um)));
  }
  if (meta.aspect) {
    check_positive3(kAspect, *meta.aspect);
    out.push_back(comment(kAspect, join3(*meta.aspect)));
  }
  if (!meta.normalization.empty()) {
    if (has_line_break(meta.normalization)) {
      throw std::invalid_argument("checkpoint metadata normalization contains a line break");
    }
    out.push_back(comment(kNormalization, meta.normalization));
  }
  if (meta.aggregation == Aggregation::kSoftmax) {
    if (!(std::isfinite(meta.beta) && meta.beta > 0.0)) {
      throw std::invalid_argument("checkpoint metadata aggregation softmax: beta " + format_number(meta.beta) +
                                  " is not a finite positive number");
    }
    out.push_back(comment(kAggregation, "softmax " + format_number(meta.beta)));
  } else if (meta.aggregation == Aggregation::kMax) {
    out.push_back(comment(kAggregation, "max"));
  }
  for (const auto& [key, value] : meta.extra) {
    if (!is_token(key) || is_known_key(key)) {
      throw std::invalid_argument("checkpoint metadata extra key '" + key +
                                  "' must be one token without blanks and not a known key");
    }
    if (has_line_break(value)) {
      throw std::invalid_argument("checkpoint metadata extra '" + key + "' contains a line break");
    }
    out.push_back(comment(key, value));
  }
  return out;
}

// The first Gaussian a checkpoint may not hold: a non-finite parameter or an
// all-zero quaternion (R(q) undefined). Problem text like "scale_1 is nan".
struct Invalid {
  std::size_t index = 0;
  std::string problem;
};

std::optional<Invalid> first_invalid(std::span<const GaussianParams> mixture) {
  for (std::size_t k = 0; k < mixture.size(); ++k) {
    const std::array<float, kGaussianParamCount> v = to_array(mixture[k]);
    // Fast scan (no early exit, vectorizable); the slow loop below names the culprit.
    bool ok = !(v[6] == 0.0f && v[7] == 0.0f && v[8] == 0.0f && v[9] == 0.0f);
    for (float x : v) ok &= std::isfinite(x);
    if (ok) continue;
    for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
      if (!std::isfinite(v[j])) return Invalid{k, std::string(kGaussianParamNames[j]) + " is " + format_number(v[j])};
    }
    return Invalid{k, "rotation rot_0..rot_3 is all zero"};
  }
  return std::nullopt;
}

// ----- reading -----

// Parses three numbers of type T, each must satisfy `valid`; fails naming the key.
template <class T, class Valid>
std::array<T, 3> parse3(const fs::path& source, std::string_view key, std::string_view value, const char* expected,
                        Valid valid) {
  const std::vector<std::string_view> tok = split_ws(value);
  std::array<T, 3> out{};
  bool ok = tok.size() == 3;
  for (std::size_t i = 0; ok && i < 3; ++i) ok = parse_number(tok[i], out[i]) && valid(out[i]);
  if (!ok) {
    io::fail_input(source, "comment hisnegs " + std::string(key) + ": expected " + expected + ", got '" +
                               std::string(value) + "'");
  }
  return out;
}

CheckpointMeta parse_meta(const std::vector<std::string>& comments, const fs::path& source) {
  CheckpointMeta meta;
  bool seen_version = false, seen_norm = false, seen_aggregation = false;
  for (const std::string& c : comments) {
    std::string_view s = c;
    if (!s.starts_with(kPrefix)) continue;
    s.remove_prefix(kPrefix.size());
    if (!s.empty() && !is_blank(s[0])) continue;  // "hisnegsfoo": someone else's comment
    while (!s.empty() && is_blank(s[0])) s.remove_prefix(1);
    std::size_t key_end = 0;
    while (key_end < s.size() && !is_blank(s[key_end])) ++key_end;
    const std::string_view key = s.substr(0, key_end);
    std::string_view value = s.substr(key_end);
    if (!value.empty()) value.remove_prefix(1);  // the one blank after the key
    if (key.empty()) io::fail_input(source, "comment 'hisnegs' without a key");

    const auto once = [&](bool seen) {
      if (seen) io::fail_input(source, "comment hisnegs " + std::string(key) + " appears twice");
    };
    if (key == kFormatVersion) {
      once(seen_version);
      seen_version = true;
      const std::vector<std::string_view> tok = split_ws(value);
      int version = 0;
      if (tok.size() != 1 || !parse_number(tok[0], version) || version < 1) {
        io::fail_input(source,
                       "comment hisnegs format_version: expected a positive integer, got '" + std::string(value) + "'");
      }
      if (version > kCheckpointFormatVersion) {
        io::fail_input(source, "checkpoint format_version " + std::to_string(version) +
                                   " is newer than this build supports (" + std::to_string(kCheckpointFormatVersion) +
                                   ")");
      }
      meta.format_version = version;
    } else if (key == kVolumeShape) {
      once(meta.volume_shape_zyx.has_value());
      meta.volume_shape_zyx =
          parse3<int>(source, key, value, "three positive integers Z Y X", [](int n) { return n > 0; });
    } else if (key == kSpacing || key == kAspect) {
      auto& field = key == kSpacing ? meta.spacing_um : meta.aspect;
      once(field.has_value());
      field = parse3<double>(source, key, value, "three finite positive numbers x y z",
                             [](double v) { return std::isfinite(v) && v > 0.0; });
    } else if (key == kNormalization) {
      once(seen_norm);
      seen_norm = true;
      meta.normalization = std::string(value);
    } else if (key == kAggregation) {
      once(seen_aggregation);
      seen_aggregation = true;
      const std::vector<std::string_view> tok = split_ws(value);
      double beta = 0;
      if (tok.size() == 1 && tok[0] == "sum") {
        meta.aggregation = Aggregation::kSum;
      } else if (tok.size() == 1 && tok[0] == "max") {
        meta.aggregation = Aggregation::kMax;
      } else if (tok.size() == 2 && tok[0] == "softmax" && parse_number(tok[1], beta) && std::isfinite(beta) &&
                 beta > 0.0) {
        meta.aggregation = Aggregation::kSoftmax;
        meta.beta = beta;
      } else {
        io::fail_input(source,
                       "comment hisnegs aggregation: expected 'sum', 'max' or 'softmax BETA' (BETA > 0), got '" +
                           io::printable(value, 80) + "'");
      }
    } else {
      meta.extra.emplace_back(std::string(key), std::string(value));
    }
  }
  return meta;
}

}  // namespace

std::vector<std::string> checkpoint_comments(const CheckpointMeta& meta) { return meta_comments(meta); }

void check_checkpoint_mixture(const GaussianMixture& mixture) {
  if (const std::optional<Invalid> bad = first_invalid(mixture)) {
    throw std::invalid_argument("gaussian " + std::to_string(bad->index) + ": " + bad->problem);
  }
}

CheckpointMeta checkpoint_meta_from_comments(const std::vector<std::string>& comments, const fs::path& source) {
  return parse_meta(comments, source);
}

std::vector<io::PlyProperty> checkpoint_properties() {
  std::vector<io::PlyProperty> props;
  props.reserve(kGaussianParamNames.size());
  for (std::string_view name : kGaussianParamNames) props.push_back({std::string(name), io::PlyType::kFloat32});
  return props;
}

io::PlyTable checkpoint_to_ply(const GaussianMixture& mixture, const CheckpointMeta& meta) {
  io::PlyTable table;
  table.comments = meta_comments(meta);
  check_checkpoint_mixture(mixture);
  io::PlyElement vertex(std::string(kVertex), static_cast<std::int64_t>(mixture.size()), checkpoint_properties());
  // The rows are exactly GaussianParams' 11 packed floats (static_asserts in the header).
  static_assert(sizeof(GaussianParams) == kGaussianParamCount * sizeof(float));
  if (!mixture.empty()) std::memcpy(vertex.bytes().data(), mixture.data(), vertex.bytes().size());
  table.elements.push_back(std::move(vertex));
  return table;
}

Checkpoint checkpoint_from_ply(const io::PlyTable& table, const fs::path& source) {
  Checkpoint out;
  // Metadata first: a newer format_version may mean the rows do not follow this layout.
  out.meta = parse_meta(table.comments, source);

  const io::PlyElement* vertex = table.find(kVertex);
  if (!vertex) io::fail_input(source, "no 'vertex' element (not a hisnegs checkpoint)");
  std::array<std::size_t, kGaussianParamCount> offset{};
  std::array<bool, kGaussianParamCount> is_double{};
  for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
    const std::string_view name = kGaussianParamNames[j];
    const std::optional<std::size_t> p = vertex->find_property(name);
    if (!p) {
      io::fail_input(source, "vertex element has no property '" + std::string(name) +
                                 "' (a checkpoint needs x y z scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 "
                                 "rot_3 intensity_logit)");
    }
    const io::PlyType type = vertex->properties()[*p].type;
    if (type != io::PlyType::kFloat32 && type != io::PlyType::kFloat64) {
      io::fail_input(source, "vertex property '" + std::string(name) + "' has type " +
                                 std::string(io::to_string(type)) + ", expected float or double");
    }
    offset[j] = vertex->offset(*p);
    is_double[j] = type == io::PlyType::kFloat64;
  }

  const auto count = static_cast<std::size_t>(vertex->count());
  out.mixture.resize(count);
  const std::byte* src = vertex->bytes().data();
  const std::size_t stride = vertex->row_size();
  bool native = stride == sizeof(GaussianParams);
  for (std::size_t j = 0; j < kGaussianParamCount; ++j) native = native && !is_double[j] && offset[j] == 4 * j;
  if (native && count > 0) {
    // The file's rows are GaussianParams already (what save_checkpoint writes): one copy.
    std::memcpy(static_cast<void*>(out.mixture.data()), src, count * stride);
  } else {
    for (std::size_t k = 0; k < count; ++k, src += stride) {
      std::array<float, kGaussianParamCount> v;
      for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
        double d;
        if (is_double[j]) {
          std::memcpy(&d, src + offset[j], sizeof d);
        } else {
          float f;
          std::memcpy(&f, src + offset[j], sizeof f);
          d = f;
        }
        // Checked before narrowing: the message shows the file's value, and an
        // out-of-range cast to float would be undefined behaviour.
        if (!std::isfinite(d) || std::abs(d) > std::numeric_limits<float>::max()) {
          const auto where = "vertex " + std::to_string(k) + ": " + std::string(kGaussianParamNames[j]);
          if (!std::isfinite(d)) io::fail_input(source, where + " is " + format_number(d));
          io::fail_input(source, where + " = " + format_number(d) + " is outside the float32 range");
        }
        v[j] = static_cast<float>(d);
      }
      out.mixture[k] = from_array(v);
      if (v[6] == 0.0f && v[7] == 0.0f && v[8] == 0.0f && v[9] == 0.0f) {
        io::fail_input(source, "vertex " + std::to_string(k) + ": rotation rot_0..rot_3 is all zero");
      }
    }
  }
  // The general layout was checked row by row above; this finds the first
  // non-finite value or all-zero quaternion of the native layout.
  if (const std::optional<Invalid> bad = first_invalid(out.mixture)) {
    io::fail_input(source, "vertex " + std::to_string(bad->index) + ": " + bad->problem);
  }
  return out;
}

void save_checkpoint(const fs::path& path, const GaussianMixture& mixture, const CheckpointMeta& meta) {
  io::PlyTable table;
  try {
    table = checkpoint_to_ply(mixture, meta);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(io::describe(path, std::string("cannot save checkpoint: ") + e.what()));
  }
  io::write_ply(path, table);
}

namespace {
std::vector<std::string> checked_comments(const fs::path& path, const CheckpointMeta& meta) {
  try {
    return meta_comments(meta);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(io::describe(path, std::string("cannot save checkpoint: ") + e.what()));
  }
}
}  // namespace

CheckpointWriter::CheckpointWriter(const fs::path& path, const CheckpointMeta& meta, std::size_t count)
    : path_(path),
      rows_(path, checked_comments(path, meta), std::string(kVertex), static_cast<std::int64_t>(count),
            checkpoint_properties()) {}

void CheckpointWriter::append(std::span<const GaussianParams> gaussians) {
  if (const std::optional<Invalid> bad = first_invalid(gaussians)) {
    throw std::invalid_argument(io::describe(
        path_, "cannot save checkpoint: gaussian " + std::to_string(appended_ + bad->index) + ": " + bad->problem));
  }
  rows_.append(std::as_bytes(gaussians));
  appended_ += gaussians.size();
}

void CheckpointWriter::commit() { rows_.commit(); }

MixtureModel model_of(const CheckpointMeta& meta, double cutoff) {
  MixtureModel m;
  m.aggregation = meta.aggregation;
  m.beta = meta.aggregation == Aggregation::kSoftmax ? meta.beta : 1.0;
  m.cutoff = cutoff;
  return m;
}

std::string describe(const MixtureModel& model) {
  if (model.aggregation == Aggregation::kSum) return "sum";
  if (model.aggregation == Aggregation::kMax) return "max";
  return "softmax (beta " + io::number_text(model.beta) + ")";
}

namespace {
constexpr const char* kBackgroundKey = "background";
constexpr const char* kRegionsKey = "background_regions";
constexpr const char* kRegionKey = "background_region";

gmf::BackgroundRegions regions_of(const CheckpointMeta& meta, std::string_view value, const std::string& source) {
  const std::vector<std::string_view> tok = split_ws(value);
  gmf::BackgroundRegions r;
  bool ok = tok.size() == 3 && meta.volume_shape_zyx.has_value();
  for (int a = 0; ok && a < 3; ++a) {
    double v = 0;
    ok = parse_number(tok[static_cast<std::size_t>(a)], v) && v >= 1 && v <= gmf::BackgroundRegions::kMaxPerAxis &&
         v == std::floor(v);
    r.cells[static_cast<std::size_t>(a)] = ok ? static_cast<int>(v) : 1;
  }
  if (ok) {
    const auto& s = *meta.volume_shape_zyx;
    r.shape = {static_cast<int>(s[2]), static_cast<int>(s[1]), static_cast<int>(s[0])};
    for (int a = 0; ok && a < 3; ++a) ok = r.cells[static_cast<std::size_t>(a)] <= r.shape[static_cast<std::size_t>(a)];
  }
  if (!ok) {
    io::fail_input(source, std::string("comment hisnegs ") + kRegionsKey + ": expected 'CX CY CZ' (1 to " +
                               std::to_string(gmf::BackgroundRegions::kMaxPerAxis) +
                               " regions per axis, no more than the volume_shape's voxels), got '" +
                               io::printable(value, 80) + "'");
  }
  return r;
}

}  // namespace

gmf::BackgroundModel background_of(const CheckpointMeta& meta, const std::string& source) {
  for (const auto& [key, value] : meta.extra) {
    if (key == kBackgroundKey) return gmf::BackgroundModel::parse(value, source);
  }
  return {};
}

void set_background(CheckpointMeta& meta, const gmf::BackgroundModel& model) {
  std::erase_if(meta.extra, [](const auto& kv) { return kv.first == kBackgroundKey; });
  if (!model.none()) meta.extra.emplace_back(kBackgroundKey, model.text());
}

gmf::BackgroundField background_field_of(const CheckpointMeta& meta, const std::string& source) {
  gmf::BackgroundField field;
  field.merged = background_of(meta, source);
  field.regions.shape = {1, 1, 1};
  if (meta.volume_shape_zyx) {
    const auto& s = *meta.volume_shape_zyx;
    field.regions.shape = {static_cast<int>(s[2]), static_cast<int>(s[1]), static_cast<int>(s[0])};
  }
  bool has_regions = false;
  for (const auto& [key, value] : meta.extra) {
    if (key == kRegionsKey) {
      field.regions = regions_of(meta, value, source);
      has_regions = true;
    }
  }
  for (const auto& [key, value] : meta.extra) {
    if (key != kRegionKey) continue;
    const std::size_t r = field.models.size();
    const std::vector<std::string_view> tok = split_ws(value);
    double index = -1;
    if (!has_regions || tok.empty() || !parse_number(tok[0], index) || index != static_cast<double>(r)) {
      io::fail_input(source, std::string("comment hisnegs ") + kRegionKey + " " + std::to_string(r) +
                                 ": expected 'R MODEL' in order after a " + kRegionsKey + " line, got '" +
                                 io::printable(value, 60) + "'");
    }
    const auto after = static_cast<std::size_t>(tok[0].data() - value.data()) + tok[0].size();
    field.models.push_back(gmf::BackgroundModel::parse(std::string_view(value).substr(after), source));
  }
  if (has_regions && field.models.size() != static_cast<std::size_t>(field.regions.count())) {
    io::fail_input(source, std::string("comment hisnegs ") + kRegionsKey + ": " +
                               std::to_string(field.regions.count()) + " regions declared, " +
                               std::to_string(field.models.size()) + " " + kRegionKey + " lines given");
  }
  if (field.models.size() == 1) field.models.clear();
  return field;
}

void set_background(CheckpointMeta& meta, const gmf::BackgroundField& field) {
  set_background(meta, field.merged);
  std::erase_if(meta.extra, [](const auto& kv) { return kv.first == kRegionsKey || kv.first == kRegionKey; });
  if (!field.regional() || field.none()) return;
  const auto& c = field.regions.cells;
  meta.extra.emplace_back(kRegionsKey, std::to_string(c[0]) + " " + std::to_string(c[1]) + " " + std::to_string(c[2]));
  for (std::size_t r = 0; r < field.models.size(); ++r) {
    meta.extra.emplace_back(kRegionKey, std::to_string(r) + " " + field.models[r].text());
  }
}

std::optional<io::WorldFrame> model_frame(const CheckpointMeta& meta) {
  if (!meta.volume_shape_zyx || !meta.aspect) return std::nullopt;
  const auto& s = *meta.volume_shape_zyx;
  const auto& a = *meta.aspect;
  return io::WorldFrame(s[2], s[1], s[0], Eigen::Vector3d(a[0], a[1], a[2]));
}

void require_same_world_box(const CheckpointMeta& meta, const io::WorldFrame& frame, const std::string& volume) {
  if (!meta.aspect) return;
  const Eigen::Vector3d model((*meta.aspect)[0], (*meta.aspect)[1], (*meta.aspect)[2]);
  const Eigen::Vector3d& a = frame.aspect();
  if (((model - a).array().abs() <= 1e-6 * model.array().abs()).all()) return;
  const auto text = [](const Eigen::Vector3d& v) {
    return io::number_text(v.x()) + " " + io::number_text(v.y()) + " " + io::number_text(v.z());
  };
  io::fail_input(volume, "its world box (aspect " + text(a) + ") differs from the model's (aspect " + text(model) +
                             "); give the --spacing / --aspect the model was fitted with");
}

}  // namespace hisnegs::gmf
