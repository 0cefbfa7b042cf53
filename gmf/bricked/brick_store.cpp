// SPDX-License-Identifier: Apache-2.0
// CentreBox and BrickStore: the brick folder's files, written atomically, read
// back with one-line errors naming the file.
#include "gmf/bricked/brick_store.hpp"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <utility>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/fault_injection.hpp"

namespace hisnegs::gmf {
namespace {

constexpr int kBrickFolderFormat = 1;

nlohmann::json counts_json(const BackgroundCounts& b) {
  nlohmann::json values = nlohmann::json::array();
  for (const auto& [v, n] : b.values) values.push_back({v, n});
  return {{"total", b.total}, {"zeros", b.zeros}, {"rounded", b.rounded}, {"values", values}};
}

// Per-region counts as [[region, counts], ...] for the regions with any.
nlohmann::json region_counts_json(const std::vector<BackgroundCounts>& regions) {
  nlohmann::json out = nlohmann::json::array();
  for (std::size_t r = 0; r < regions.size(); ++r) {
    if (regions[r].total > 0) out.push_back({r, counts_json(regions[r])});
  }
  return out;
}

BackgroundCounts counts_from(const nlohmann::json& j) {
  BackgroundCounts b;
  b.rounded = j.at("rounded").get<bool>();
  for (const auto& pair : j.at("values")) b.values[pair.at(0).get<float>()] += pair.at(1).get<std::int64_t>();
  b.total = j.at("total").get<std::int64_t>();
  b.zeros = j.at("zeros").get<std::int64_t>();
  return b;
}

std::vector<BackgroundCounts> region_counts_from(const nlohmann::json& j, int regions) {
  std::vector<BackgroundCounts> out(static_cast<std::size_t>(regions));
  for (const auto& pair : j) {
    const auto r = pair.at(0).get<std::size_t>();
    if (r >= out.size()) throw std::out_of_range("background region " + std::to_string(r));
    out[r] = counts_from(pair.at(1));
  }
  return out;
}

nlohmann::json log_json(const std::vector<FitIteration>& log) {
  nlohmann::json out = nlohmann::json::array();
  for (const FitIteration& it : log) {
    out.push_back({it.round, it.iteration, it.seconds, it.loss, it.psnr_fg, it.psnr_3d, it.gaussians, it.beta});
  }
  return out;
}

std::vector<FitIteration> log_from(const nlohmann::json& j) {
  std::vector<FitIteration> log;
  for (const auto& row : j) {
    FitIteration it;
    it.round = row.at(0).get<int>();
    it.iteration = row.at(1).get<int>();
    it.seconds = row.at(2).get<double>();
    it.loss = row.at(3).get<double>();
    it.psnr_fg = row.at(4).get<double>();
    it.psnr_3d = row.at(5).get<double>();
    it.gaussians = row.at(6).get<int>();
    it.beta = row.at(7).get<double>();
    log.push_back(it);
  }
  return log;
}

}  // namespace

void CentreBox::add(const Eigen::Vector3d& ijk) {
  for (int a = 0; a < 3; ++a) {
    lo[a] = empty ? ijk[a] : std::min(lo[a], ijk[a]);
    hi[a] = empty ? ijk[a] : std::max(hi[a], ijk[a]);
  }
  empty = false;
}

void CentreBox::add(const CentreBox& o) {
  if (o.empty) return;
  add(Eigen::Vector3d(o.lo[0], o.lo[1], o.lo[2]));
  add(Eigen::Vector3d(o.hi[0], o.hi[1], o.hi[2]));
}

CentreBox CentreBox::spanning(const double* lo, const double* hi) {
  CentreBox box;
  box.add(Eigen::Vector3d(lo[0], lo[1], lo[2]));
  box.add(Eigen::Vector3d(hi[0], hi[1], hi[2]));
  return box;
}

bool CentreBox::meets(const io::VoxelBox& box, const std::array<int, 3>& grow) const {
  if (empty) return false;
  for (int a = 0; a < 3; ++a) {
    if (hi[a] < box.lo[a] - grow[a] - 0.5 || lo[a] >= box.hi[a] + grow[a] - 0.5) return false;
  }
  return true;
}

CentreBox centre_box(const io::WorldFrame& frame, const GaussianMixture& m) {
  CentreBox box;
  for (const GaussianParams& g : m) box.add(frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2])));
  return box;
}

std::filesystem::path brick_folder(const std::filesystem::path& out) {
  std::filesystem::path dir = out;
  dir += ".bricks";
  return dir;
}

BrickStore::BrickStore(std::filesystem::path folder, std::string fingerprint, const io::WorldFrame& frame,
                       int regions)
    : folder_(std::move(folder)), fingerprint_(std::move(fingerprint)), frame_(frame), regions_(regions) {}

std::filesystem::path BrickStore::path(int id, const char* ext) const {
  char name[32];
  std::snprintf(name, sizeof name, "brick_%05d.%s", id, ext);
  return folder_ / name;
}

std::filesystem::path BrickStore::held_path(int rank) const {
  return folder_ / ("rank-" + std::to_string(rank) + ".holds");
}

std::filesystem::path BrickStore::stopped_path(int rank) const {
  return folder_ / ("rank-" + std::to_string(rank) + ".stopped");
}

std::optional<BrickStore::Existing> BrickStore::read_plan() const {
  const std::filesystem::path plan_file = folder_ / "plan.json";
  if (!std::filesystem::exists(plan_file)) return std::nullopt;
  nlohmann::json j;
  try {
    std::ifstream in(plan_file);
    j = nlohmann::json::parse(in);
  } catch (const std::exception&) {
    io::fail_input(plan_file, "not a hisnegs brick plan; remove the folder or choose another -o");
  }
  if (!j.is_object() || j.value("fingerprint", std::string()) != fingerprint_) {
    io::fail_input(folder_, "holds the bricks of another stack, config or plan (" +
                                (j.is_object() ? j.value("stack", std::string("?")) : std::string("?")) +
                                "); remove it or choose another -o");
  }
  Existing existing;
  if (!j.contains("raw_lo")) return existing;
  const auto field = [&]<typename T>(const char* key, T& to, const char* what) {
    try {
      to = j.at(key).get<T>();
    } catch (const nlohmann::json::exception&) {
      io::fail_input(plan_file, std::string("field '") + key + "' is missing or not " + what +
                                    ": not a hisnegs brick plan; remove the folder or choose another -o");
    }
  };
  PlanStatistics s;
  field("raw_lo", s.raw_lo, "a number");
  field("raw_hi", s.raw_hi, "a number");
  field("foreground", s.foreground, "an integer");
  if (j.contains("core_foreground")) field("core_foreground", s.core_foreground, "a list of integers");
  existing.statistics = std::move(s);
  return existing;
}

void BrickStore::write_plan(const std::string& stack, const BrickPlan& plan, const io::Normalization& normalization,
                            const PlanStatistics& statistics, std::uint64_t voxels) const {
  std::filesystem::create_directories(folder_);
  nlohmann::json j;
  j["format"] = kBrickFolderFormat;
  j["fingerprint"] = fingerprint_;
  j["stack"] = stack;
  j["plan"] = plan.describe();
  j["normalization"] = normalization.describe();
  j["raw_lo"] = normalization.raw_lo;
  j["raw_hi"] = normalization.raw_hi;
  j["foreground"] = statistics.foreground;
  if (!statistics.core_foreground.empty()) j["core_foreground"] = statistics.core_foreground;
  j["voxels"] = voxels;
  const std::string text = j.dump(2) + "\n";
  io::write_file_atomic(folder_ / "plan.json", text.data(), text.size());
}

void BrickStore::save(int id, const BrickRecord& r) const {
  io::fault_point("brick-save");
  CheckpointMeta meta;
  meta.extra.emplace_back("brick", std::to_string(id));
  save_checkpoint(path(id, "ply"), r.kept, meta);
  nlohmann::json j = {{"fingerprint", fingerprint_},
                      {"brick", id},
                      {"kept", r.count},
                      {"foreground_core", r.foreground_core},
                      {"samples", r.samples},
                      {"seconds", r.seconds},
                      {"final_beta", r.final_beta},
                      {"background", region_counts_json(r.background)},
                      {"log", log_json(r.log)}};
  if (!r.centres.empty) j["centres"] = {r.centres.lo, r.centres.hi};
  const std::string text = j.dump() + "\n";
  io::write_file_atomic(path(id, "json"), text.data(), text.size());
}

GaussianMixture BrickStore::load_gaussians(int id, const char* kind, std::size_t count) const {
  GaussianMixture m = load_checkpoint(path(id, kind)).mixture;
  if (m.size() != count) {
    io::fail_input(path(id, kind),
                   "holds " + std::to_string(m.size()) + " Gaussians, its brick record " + std::to_string(count));
  }
  return m;
}

std::optional<BrickRecord> BrickStore::load(int id) const {
  const std::filesystem::path json_path = path(id, "json");
  if (!std::filesystem::exists(json_path)) return std::nullopt;
  BrickRecord r;
  try {
    std::ifstream in(json_path);
    const nlohmann::json j = nlohmann::json::parse(in);
    if (j.at("fingerprint").get<std::string>() != fingerprint_ || j.at("brick").get<int>() != id) {
      io::fail_input(json_path, "belongs to another fit; remove the folder or choose another -o");
    }
    r.foreground_core = j.at("foreground_core").get<std::int64_t>();
    r.samples = j.at("samples").get<std::int64_t>();
    r.seconds = j.at("seconds").get<double>();
    r.final_beta = j.at("final_beta").get<double>();
    r.background = region_counts_from(j.at("background"), regions_);
    r.log = log_from(j.at("log"));
    r.count = j.at("kept").get<std::size_t>();
    if (j.contains("centres")) {
      const auto lo = j.at("centres").at(0).get<std::array<double, 3>>();
      const auto hi = j.at("centres").at(1).get<std::array<double, 3>>();
      r.centres = CentreBox::spanning(lo.data(), hi.data());
    } else if (r.count > 0) {  // a record of an earlier build: read the Gaussians once
      r.centres = centre_box(frame_, load_gaussians(id, "ply", r.count));
    }
  } catch (const nlohmann::json::exception& e) {
    io::fail_input(json_path, std::string("not a hisnegs brick record: ") + e.what());
  }
  return r;
}

void BrickStore::save_seam(int id, const GaussianMixture& m) const {
  CheckpointMeta meta;
  meta.extra.emplace_back("brick", std::to_string(id));
  save_checkpoint(path(id, "seam.ply"), m, meta);
}

void BrickStore::write_checkpoint(const std::vector<std::size_t>& count, const char* kind,
                                  const std::filesystem::path& out, const CheckpointMeta& meta) const {
  std::size_t total = 0;
  for (std::size_t k : count) total += k;
  CheckpointWriter writer(out, meta, total);
  for (std::size_t id = 0; id < count.size(); ++id) {
    if (count[id] > 0) writer.append(load_gaussians(static_cast<int>(id), kind, count[id]));
  }
  writer.commit();
}

}  // namespace hisnegs::gmf
