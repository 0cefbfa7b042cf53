// SPDX-License-Identifier: Apache-2.0
// Camera intrinsics, orbit poses and cameras.json (nlohmann::json).
#include "splat/camera.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <sstream>
#include <utility>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::splat {
namespace {
constexpr double kDegToRad = std::numbers::pi / 180.0;

std::string indexed_name(const char* prefix, std::size_t i) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s_%03zu", prefix, i);
  return buf;
}
}  // namespace

Intrinsics make_intrinsics(const CameraOptions& options) {
  options.validate();
  Intrinsics K;
  K.width = options.width;
  K.height = options.height;
  K.fx = K.fy = (options.width / 2.0) / std::tan(options.fov_deg * kDegToRad / 2.0);
  K.cx = options.width / 2.0;
  K.cy = options.height / 2.0;
  K.near = options.near;
  K.far = options.far;
  return K;
}

CameraView orbit_view(double elevation_deg, double azimuth_deg, double radius, std::string name) {
  const double e = elevation_deg * kDegToRad, phi = azimuth_deg * kDegToRad;
  const Eigen::Vector3d C =
      radius * Eigen::Vector3d(std::cos(e) * std::cos(phi), std::cos(e) * std::sin(phi), std::sin(e));
  const Eigen::Vector3d z = -C.normalized();
  const Eigen::Vector3d up = std::abs(std::sin(e)) > 0.999 ? Eigen::Vector3d(0, 1, 0) : Eigen::Vector3d(0, 0, 1);
  const Eigen::Vector3d x = z.cross(up).normalized();
  const Eigen::Vector3d y = z.cross(x);
  CameraView view;
  view.name = std::move(name);
  view.R_cam_from_world.row(0) = x;
  view.R_cam_from_world.row(1) = y;
  view.R_cam_from_world.row(2) = z;
  view.t_cam_from_world = -view.R_cam_from_world * C;
  return view;
}

std::vector<double> even_azimuths(int count, double azimuth0_deg) {
  std::vector<double> a;
  a.reserve(static_cast<std::size_t>(std::max(0, count)));
  for (int j = 0; j < count; ++j) a.push_back(360.0 * j / count + azimuth0_deg);
  return a;
}

CameraSet training_orbit(const CameraOptions& options) {
  CameraSet set{make_intrinsics(options), {}};
  const double elevations[] = {-30.0, 0.0, 30.0, 60.0};
  const int counts[] = {27, 27, 26, 26};
  for (int ring = 0; ring < 4; ++ring) {
    for (int j = 0; j < counts[ring]; ++j) {
      const double phi = 360.0 * (j + 0.5 * (ring % 2)) / counts[ring];
      set.views.push_back(
          orbit_view(elevations[ring], phi, options.orbit_radius, indexed_name("train", set.views.size())));
    }
  }
  return set;
}

CameraSet evaluation_orbit(const CameraOptions& options) {
  CameraSet set{make_intrinsics(options), {}};
  for (double e : {-15.0, 15.0, 45.0}) {
    for (double phi : even_azimuths(10, 18.0)) {
      set.views.push_back(orbit_view(e, phi, options.orbit_radius, indexed_name("eval", set.views.size())));
    }
  }
  return set;
}

CameraSet close_views(const CameraOptions& options) {
  CameraSet set{make_intrinsics(options), {}};
  constexpr int kPerRing = CameraOptions::kCloseViewsPerRadius / 4;
  for (const double f : options.close_radii) {
    int ring = 0;
    for (const double e : {-30.0, 0.0, 30.0, 60.0}) {
      for (int j = 0; j < kPerRing; ++j) {
        const double phi = 360.0 * (j + 0.25 + 0.5 * (ring % 2)) / kPerRing;
        set.views.push_back(orbit_view(e, phi, f * options.orbit_radius, indexed_name("close", set.views.size())));
      }
      ++ring;
    }
  }
  return set;
}

CameraSet custom_orbit(const CameraOptions& options, const std::vector<double>& elevations_deg,
                       const std::vector<double>& azimuths_deg) {
  CameraSet set{make_intrinsics(options), {}};
  for (double e : elevations_deg) {
    if (!(e >= -90.0 && e <= 90.0))
      throw io::InputError("--elevations: " + std::to_string(e) + " is outside [-90, 90]");
    for (double phi : azimuths_deg) {
      set.views.push_back(orbit_view(e, phi, options.orbit_radius, indexed_name("view", set.views.size())));
    }
  }
  if (set.views.empty()) throw io::InputError("orbit: no views (give at least one elevation and one azimuth)");
  return set;
}

Eigen::Vector3d project(const Intrinsics& K, const CameraView& view, const Eigen::Vector3d& p_world) {
  const Eigen::Vector3d p = view.R_cam_from_world * p_world + view.t_cam_from_world;
  return {K.fx * p.x() / p.z() + K.cx, K.fy * p.y() / p.z() + K.cy, p.z()};
}

Eigen::Vector3d ray_direction(const Intrinsics& K, const CameraView& view, double u, double v) {
  const Eigen::Vector3d d_cam((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
  return (view.R_cam_from_world.transpose() * d_cam).normalized();
}

std::string cameras_json_text(const CameraSet& cameras) {
  nlohmann::ordered_json j;
  const Intrinsics& K = cameras.intrinsics;
  j["width"] = K.width;
  j["height"] = K.height;
  j["fx"] = K.fx;
  j["fy"] = K.fy;
  j["cx"] = K.cx;
  j["cy"] = K.cy;
  j["near"] = K.near;
  j["far"] = K.far;
  j["views"] = nlohmann::ordered_json::array();
  for (const CameraView& v : cameras.views) {
    nlohmann::ordered_json jv;
    jv["name"] = v.name;
    jv["R"] = nlohmann::ordered_json::array();
    for (int r = 0; r < 3; ++r) {
      jv["R"].push_back({v.R_cam_from_world(r, 0), v.R_cam_from_world(r, 1), v.R_cam_from_world(r, 2)});
    }
    jv["T"] = {v.t_cam_from_world.x(), v.t_cam_from_world.y(), v.t_cam_from_world.z()};
    j["views"].push_back(std::move(jv));
  }
  // nlohmann writes doubles with max_digits10: the file round-trips bit-exactly.
  return j.dump(1) + "\n";
}

void write_cameras_json(const std::filesystem::path& path, const CameraSet& cameras) {
  const std::string text = cameras_json_text(cameras);
  io::write_file_atomic(path, text.data(), text.size());
}

namespace {

using Json = nlohmann::json;

// A value for a message: scalars as written, arrays and objects by kind only
// (dump() recurses, so a hostile deeply nested value would overflow the stack).
std::string describe_value(const Json& value) {
  if (value.is_array()) return "an array";
  if (value.is_object()) return "an object";
  return io::printable(value.dump(), 80);
}

class JsonReader {
 public:
  explicit JsonReader(std::filesystem::path path) : path_(std::move(path)) {}
  // `where` and `what` may quote the file (keys, values): printable() keeps the message one line.
  [[noreturn]] void fail(const std::string& where, const std::string& what) const {
    io::fail_input(path_, io::printable(where.empty() ? what : where + ": " + what));
  }
  double number(const Json& obj, const std::string& key, const std::string& where) const {
    const auto it = obj.find(key);
    if (it == obj.end()) fail(where, "missing key '" + key + "'");
    if (!it->is_number()) fail(where + key, "expected a number, got " + describe_value(*it));
    const double v = it->get<double>();
    if (!std::isfinite(v)) fail(where + key, "is not finite");
    return v;
  }
  int integer(const Json& obj, const std::string& key) const {
    const auto it = obj.find(key);
    if (it == obj.end()) fail("", "missing key '" + key + "'");
    if (!it->is_number_integer()) fail(key, "expected an integer, got " + describe_value(*it));
    // get<int>() would silently wrap a larger value (4294967297 -> 1).
    const bool fits = it->is_number_unsigned() ? std::in_range<int>(it->get<std::uint64_t>())
                                               : std::in_range<int>(it->get<std::int64_t>());
    if (!fits) {
      fail(key, it->dump() + " is out of range (at most " + std::to_string(std::numeric_limits<int>::max()) + ")");
    }
    return it->get<int>();
  }
  void only_keys(const Json& obj, const std::set<std::string>& allowed, const std::string& where) const {
    for (const auto& [k, v] : obj.items()) {
      if (!allowed.count(k)) fail(where.empty() ? k : where + k, "unknown key");
    }
  }

 private:
  std::filesystem::path path_;
};

}  // namespace

CameraSet read_cameras_json(const std::filesystem::path& path) {
  io::require_regular_file(path);
  std::ifstream in(path, std::ios::binary);
  Json j;
  try {
    j = Json::parse(in);
  } catch (const Json::exception& e) {
    io::fail_input(path, "invalid JSON: " + io::printable(e.what()));
  }
  const JsonReader r(path);
  if (!j.is_object()) r.fail("top level", "expected an object");
  r.only_keys(j, {"width", "height", "fx", "fy", "cx", "cy", "near", "far", "views"}, "");
  CameraSet set;
  Intrinsics& K = set.intrinsics;
  K.width = r.integer(j, "width");
  K.height = r.integer(j, "height");
  // The same bound as the config's camera.width/height: a hostile size gets an
  // error here, not an out-of-memory failure in the renderer.
  if (K.width <= 0 || K.height <= 0 || K.width > kMaxImageSide || K.height > kMaxImageSide) {
    r.fail("width/height", std::to_string(K.width) + "x" + std::to_string(K.height) + " is outside [1, " +
                               std::to_string(kMaxImageSide) + "]");
  }
  K.fx = r.number(j, "fx", "");
  K.fy = r.number(j, "fy", "");
  K.cx = r.number(j, "cx", "");
  K.cy = r.number(j, "cy", "");
  K.near = r.number(j, "near", "");
  K.far = r.number(j, "far", "");
  if (K.fx <= 0 || K.fy <= 0) r.fail("fx/fy", "must be positive");
  if (!(K.near > 0 && K.far > K.near)) r.fail("near/far", "need 0 < near < far");
  const auto views = j.find("views");
  if (views == j.end() || !views->is_array()) r.fail("views", "missing or not a list");
  if (views->empty()) r.fail("views", "is empty");
  io::check_allocation(
      path, 4.0 * K.width * K.height * static_cast<double>(views->size()),
      std::to_string(views->size()) + " float32 images of " + std::to_string(K.width) + "x" + std::to_string(K.height));
  for (std::size_t i = 0; i < views->size(); ++i) {
    const Json& jv = (*views)[i];
    const std::string where = "views[" + std::to_string(i) + "].";
    if (!jv.is_object()) r.fail(where, "expected an object");
    r.only_keys(jv, {"name", "R", "T"}, where);
    CameraView v;
    const auto name = jv.find("name");
    if (name == jv.end() || !name->is_string()) r.fail(where + "name", "missing or not a string");
    v.name = name->get<std::string>();
    const auto R = jv.find("R");
    if (R == jv.end() || !R->is_array() || R->size() != 3) r.fail(where + "R", "expected 3 rows of 3 numbers");
    for (int row = 0; row < 3; ++row) {
      const Json& jr = (*R)[row];
      if (!jr.is_array() || jr.size() != 3) r.fail(where + "R", "expected 3 rows of 3 numbers");
      for (int c = 0; c < 3; ++c) {
        if (!jr[c].is_number() || !std::isfinite(jr[c].get<double>()))
          r.fail(where + "R", "non-numeric or non-finite entry");
        v.R_cam_from_world(row, c) = jr[c].get<double>();
      }
    }
    const auto T = jv.find("T");
    if (T == jv.end() || !T->is_array() || T->size() != 3) r.fail(where + "T", "expected 3 numbers");
    for (int c = 0; c < 3; ++c) {
      if (!(*T)[c].is_number() || !std::isfinite((*T)[c].get<double>()))
        r.fail(where + "T", "non-numeric or non-finite entry");
      v.t_cam_from_world(c) = (*T)[c].get<double>();
    }
    const double orth =
        (v.R_cam_from_world * v.R_cam_from_world.transpose() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    const double det = v.R_cam_from_world.determinant();
    if (orth > 1e-6 || std::abs(det - 1.0) > 1e-6) {
      std::ostringstream s;
      s << "not a rotation (max |R Rᵀ - I| = " << orth << ", det = " << det << ")";
      r.fail(where + "R", s.str());
    }
    set.views.push_back(std::move(v));
  }
  return set;
}

}  // namespace hisnegs::splat
