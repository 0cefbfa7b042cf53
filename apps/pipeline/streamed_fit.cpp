// SPDX-License-Identifier: Apache-2.0
// choose_fit_plan and fit_streamed: statistics, plan, the brick folder (plan.json
// with the fingerprint of stack and config; brick_NNNNN.ply + .json per finished
// brick), the brick pass, the seam pass, the measuring pass and the checkpoint.
#include "apps/pipeline/streamed_fit.hpp"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/interrupts.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "apps/pipeline/stage_folder.hpp"
#include "gmf/core/density_ops.hpp"
#include "gmf/core/psnr.hpp"
#include "gmf/core/rasterize.hpp"
#include "gmf/fit.hpp"
#include "gmf/init.hpp"
#include "io/atomic_file.hpp"
#include "gmf/core/background.hpp"
#include "io/error.hpp"
#include "io/fault_injection.hpp"
#include "io/folder_lock.hpp"
#include "io/hash.hpp"
#include "io/memory_limit.hpp"
#include "io/stack_file.hpp"
#include "io/timer.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::apps {
namespace {

constexpr int kBrickFolderFormat = 1;

// The largest scale of a bricked fit, world units (gmf.stream_scale_voxels smallest voxels).
double brick_max_scale(const io::WorldFrame& frame, const gmf::GmfOptions& gmf) {
  return gmf.stream_scale_voxels * frame.voxel_size().minCoeff();
}

std::size_t region_voxels(const std::array<int, 3>& shape, int core, const std::array<int, 3>& halo) {
  std::size_t n = 1;
  for (int a = 0; a < 3; ++a) n *= static_cast<std::size_t>(std::min(shape[a], std::min(core, shape[a]) + 2 * halo[a]));
  return n;
}

}  // namespace

std::filesystem::path brick_folder(const std::filesystem::path& out) {
  std::filesystem::path dir = out;
  dir += ".bricks";
  return dir;
}

int largest_core(const std::array<int, 3>& shape, int smallest, double bytes, const std::function<double(int)>& need) {
  int core = *std::max_element(shape.begin(), shape.end());
  while (core > smallest && need(core) > bytes) core = std::max(smallest, (core * 3 / 4) / 16 * 16);
  return core;
}

FitPlanChoice choose_fit_plan(const std::array<int, 3>& shape, const io::WorldFrame& frame, const gmf::GmfOptions& gmf,
                              const FitMemoryModel& memory, int ranks) {
  FitPlanChoice c;
  const io::MemoryLimit limit = io::resolve_memory_limit(gmf.max_memory, "gmf.max_memory");
  c.max_memory = limit.bytes;
  c.memory_source = limit.source;
  const std::size_t voxels = static_cast<std::size_t>(shape[0]) * shape[1] * shape[2];
  const auto K = static_cast<std::size_t>(gmf.gaussians);
  c.whole_need = memory.need(voxels, K);
  const bool fits = c.whole_need <= c.max_memory;
  if (gmf.stream_brick_voxels == 0 && fits && ranks <= 1) return c;  // today's fit
  c.bricked = true;
  const std::array<int, 3> halo = gmf::halo_voxels(frame, gmf.mahalanobis_cutoff, brick_max_scale(frame, gmf));
  const int smallest = std::max(16, 2 * *std::max_element(halo.begin(), halo.end()));
  int core = gmf.stream_brick_voxels > 0 ? gmf.stream_brick_voxels
                                         : largest_core(shape, smallest, c.max_memory, [&](int edge) {
                                             return memory.need(region_voxels(shape, edge, halo), K);
                                           });
  if (gmf.stream_brick_voxels == 0 && ranks > 1) {  // no brick size asked for: two or more per rank
    core = core_for_ranks(shape, ranks, core, smallest);
    c.for_ranks = true;
  }
  c.brick_need = memory.need(region_voxels(shape, core, halo), K);
  if (c.brick_need > c.max_memory) {
    throw io::InputError("gmf.max_memory = " + gmf.max_memory + ": too small for this fit: a brick of core " +
                         std::to_string(core) + " voxels with its halo (" + std::to_string(halo[0]) + " x " +
                         std::to_string(halo[1]) + " x " + std::to_string(halo[2]) + ") and a model of K " +
                         std::to_string(K) + " need " + io::gib_text(c.brick_need) + "; allow at least that");
  }
  double bricks = 1.0;  // counted before they are planned
  for (int a = 0; a < 3; ++a) bricks *= std::ceil(static_cast<double>(shape[a]) / core);
  if (bricks > gmf::GmfOptions::kMostStreamBricks) {
    throw io::InputError("gmf.stream_brick_voxels = " + std::to_string(core) + ": " + io::number_text(bricks) +
                         " bricks of core " + std::to_string(core) + " voxels for this stack, more than the limit of " +
                         std::to_string(gmf::GmfOptions::kMostStreamBricks) + "; use larger bricks (--brick-voxels)");
  }
  c.plan = gmf::plan_bricks(shape, {core, core, core}, halo);
  return c;
}

namespace {

// What every brick of one fit shares.
struct StreamContext {
  std::string path;
  const FitConfig* config = nullptr;
  gmf::GmfOptions gmf;  // the config's, with the bricked fit's scale bound
  std::unique_ptr<io::VolumeSource> source;
  io::Normalization normalization;
  io::WorldFrame frame;
  gmf::BrickPlan plan;
  std::int64_t foreground = 0;                // voxels above sparse_grid.threshold, whole stack
  std::vector<std::int64_t> core_foreground;  // per brick (its core); counted on several ranks only
  double max_memory = 0;                      // bytes (FitPlanChoice)
  std::string fingerprint;
  std::filesystem::path folder;
  gmf::BackgroundRegions regions;  // of the stack's background (background.region_voxels)
};

// Raw values of `box`, normalized as the whole stack is.
io::Volume read_region(const StreamContext& c, const io::VoxelBox& box) {
  io::Volume v;
  v.nx = box.hi[0] - box.lo[0];
  v.ny = box.hi[1] - box.lo[1];
  v.nz = box.hi[2] - box.lo[2];
  v.voxels.resize(box.voxels());
  c.source->read(box, v.voxels.data());
  for (float x : v.voxels) {
    if (!std::isfinite(x)) io::fail_input(c.path, "holds a non-finite value; cannot normalize");
  }
  (void)io::apply_normalization(v.voxels, c.normalization);
  v.normalization = c.normalization;
  v.stored_as = c.source->stored_as;
  v.spacing = c.source->spacing;
  v.source = c.path;
  return v;
}

std::int64_t count_above(std::span<const float> values, double threshold) {
  return std::count_if(values.begin(), values.end(), [&](float v) { return v > threshold; });
}

std::int64_t count_above(const io::Volume& v, const io::VoxelBox& box, double threshold) {
  std::int64_t n = 0;
  for (int z = box.lo[2]; z < box.hi[2]; ++z) {
    for (int y = box.lo[1]; y < box.hi[1]; ++y) {
      const float* row = &v.voxels[v.index(box.lo[0], y, z)];
      n += count_above(std::span<const float>(row, static_cast<std::size_t>(box.hi[0] - box.lo[0])), threshold);
    }
  }
  return n;
}

// The box `b` in the index space of `region`.
io::VoxelBox local_box(const io::VoxelBox& b, const io::VoxelBox& region) {
  io::VoxelBox l;
  for (int a = 0; a < 3; ++a) {
    l.lo[a] = b.lo[a] - region.lo[a];
    l.hi[a] = b.hi[a] - region.lo[a];
  }
  return l;
}

void shift_means(gmf::GaussianMixture& m, const Eigen::Vector3d& shift) {
  for (gmf::GaussianParams& g : m) {
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(static_cast<double>(g.mean[a]) + shift[a]);
  }
}

Eigen::Vector3d index_of(const StreamContext& c, const gmf::GaussianParams& g) {
  return c.frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
}

// True when the centre (continuous index) lies within `halo` of `box` grown by `grow` voxels.
bool within(const Eigen::Vector3d& ijk, const io::VoxelBox& box, const std::array<int, 3>& grow) {
  for (int a = 0; a < 3; ++a) {
    if (ijk[a] < box.lo[a] - grow[a] - 0.5 || ijk[a] >= box.hi[a] + grow[a] - 0.5) return false;
  }
  return true;
}

// The bounding box of a brick's Gaussian centres (continuous index): which other
// bricks' regions (grown by the halo) its Gaussians can be within, so that a rank
// reads or is sent only the bricks it needs.
struct CentreBox {
  std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  bool empty = true;
  void add(const Eigen::Vector3d& ijk) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = empty ? ijk[a] : std::min(lo[a], ijk[a]);
      hi[a] = empty ? ijk[a] : std::max(hi[a], ijk[a]);
    }
    empty = false;
  }
  void add(const CentreBox& o) {
    if (o.empty) return;
    add(Eigen::Vector3d(o.lo[0], o.lo[1], o.lo[2]));
    add(Eigen::Vector3d(o.hi[0], o.hi[1], o.hi[2]));
  }
  // The box from `lo` to `hi` (as recorded in a brick record or sent by a rank).
  static CentreBox spanning(const double* lo, const double* hi) {
    CentreBox box;
    box.add(Eigen::Vector3d(lo[0], lo[1], lo[2]));
    box.add(Eigen::Vector3d(hi[0], hi[1], hi[2]));
    return box;
  }
  // Whether a centre in the box may be within(·, box, grow).
  [[nodiscard]] bool meets(const io::VoxelBox& box, const std::array<int, 3>& grow) const {
    if (empty) return false;
    for (int a = 0; a < 3; ++a) {
      if (hi[a] < box.lo[a] - grow[a] - 0.5 || lo[a] >= box.hi[a] + grow[a] - 0.5) return false;
    }
    return true;
  }
};

// The Gaussians of `m` within(·, box, halo) of one of `boxes`, in order.
gmf::GaussianMixture within_any(const StreamContext& c, const gmf::GaussianMixture& m,
                                const std::vector<const io::VoxelBox*>& boxes) {
  gmf::GaussianMixture near;
  for (const gmf::GaussianParams& g : m) {
    const Eigen::Vector3d ijk = index_of(c, g);
    if (std::any_of(boxes.begin(), boxes.end(),
                    [&](const io::VoxelBox* box) { return within(ijk, *box, c.plan.halo); })) {
      near.push_back(g);
    }
  }
  return near;
}

CentreBox centre_box(const StreamContext& c, const gmf::GaussianMixture& m) {
  CentreBox box;
  for (const gmf::GaussianParams& g : m) box.add(index_of(c, g));
  return box;
}

// "brick 6/16 (cell 1,1,0)": how every line names a brick.
std::string brick_text(const StreamContext& c, const gmf::StreamBrick& b) {
  return strf("brick %d/%zu (cell %d,%d,%d)", b.id + 1, c.plan.bricks.size(), b.cell[0], b.cell[1], b.cell[2]);
}

// ---- the brick folder ------------------------------------------------------

std::filesystem::path brick_path(const StreamContext& c, int id, const char* ext) {
  char name[32];
  std::snprintf(name, sizeof name, "brick_%05d.%s", id, ext);
  return c.folder / name;
}

// The fingerprint of what decides the bricks: the stack (path, size, time, shape),
// the fit's config sections and the plan.
std::string fingerprint_of(const std::string& path, const io::VolumeSource& source, const FitConfig& config,
                           const gmf::BrickPlan& plan) {
  AppConfig slice;
  slice.volume = config.get<&AppConfig::volume>();
  slice.background = config.get<&AppConfig::background>();
  slice.sparse_grid = config.get<&AppConfig::sparse_grid>();
  slice.gmf = config.get<&AppConfig::gmf>();
  std::ostringstream s;
  s << std::filesystem::absolute(path).lexically_normal().string() << "\n";
  for (const std::filesystem::path& file : io::stack_files(path)) {  // a BigDataViewer .xml: its .h5 too
    std::error_code ec;
    s << std::filesystem::file_size(file, ec) << " "
      << std::filesystem::last_write_time(file, ec).time_since_epoch().count() << "\n";
  }
  s << source.nx << " " << source.ny << " " << source.nz << "\n" << plan.describe() << "\n" << dump_app_config(slice);
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(io::fnv1a64(s.str())));
  return hex;
}

// The plan.json of this fit's brick folder, if there is one; one of another stack,
// config or plan (or not a plan) is refused.
std::optional<nlohmann::json> existing_plan(const StreamContext& c) {
  const std::filesystem::path plan_file = c.folder / "plan.json";
  if (!std::filesystem::exists(plan_file)) return std::nullopt;
  nlohmann::json j;
  try {
    std::ifstream in(plan_file);
    j = nlohmann::json::parse(in);
  } catch (const std::exception&) {
    io::fail_input(plan_file, "not a hisnegs brick plan; remove the folder or choose another -o");
  }
  if (!j.is_object() || j.value("fingerprint", std::string()) != c.fingerprint) {
    io::fail_input(c.folder, "holds the bricks of another stack, config or plan (" +
                                 (j.is_object() ? j.value("stack", std::string("?")) : std::string("?")) +
                                 "); remove it or choose another -o");
  }
  return j;
}

// Creates the folder's plan.json: the fingerprint and the statistics a resume reuses.
void write_plan(const StreamContext& c, const io::SourceStatistics& stats) {
  std::filesystem::create_directories(c.folder);
  nlohmann::json j;
  j["format"] = kBrickFolderFormat;
  j["fingerprint"] = c.fingerprint;
  j["stack"] = c.path;
  j["plan"] = c.plan.describe();
  j["normalization"] = c.normalization.describe();
  j["raw_lo"] = c.normalization.raw_lo;
  j["raw_hi"] = c.normalization.raw_hi;
  j["foreground"] = c.foreground;
  if (!c.core_foreground.empty()) j["core_foreground"] = c.core_foreground;
  j["voxels"] = stats.voxels;
  const std::string text = j.dump(2) + "\n";
  io::write_file_atomic(c.folder / "plan.json", text.data(), text.size());
}

// What a finished brick leaves: its Gaussians (brick_N.ply) and this (brick_N.json,
// written last: a brick is finished when it exists).
struct BrickResult {
  gmf::GaussianMixture kept;  // empty once saved: the bricks stay in the folder, not in memory
  std::size_t count = 0;      // Gaussians kept
  CentreBox centres;
  std::vector<gmf::BackgroundCounts> background;  // per region of the stack's BackgroundRegions, or empty
  std::vector<gmf::FitIteration> log;
  std::int64_t foreground_core = 0;
  std::int64_t samples = 0;
  double seconds = 0;
  double final_beta = 0;
};

nlohmann::json counts_json(const gmf::BackgroundCounts& b) {
  nlohmann::json values = nlohmann::json::array();
  for (const auto& [v, n] : b.values) values.push_back({v, n});
  return {{"total", b.total}, {"zeros", b.zeros}, {"rounded", b.rounded}, {"values", values}};
}

// Per-region counts as [[region, counts], ...] for the regions with any.
nlohmann::json region_counts_json(const std::vector<gmf::BackgroundCounts>& regions) {
  nlohmann::json out = nlohmann::json::array();
  for (std::size_t r = 0; r < regions.size(); ++r) {
    if (regions[r].total > 0) out.push_back({r, counts_json(regions[r])});
  }
  return out;
}

gmf::BackgroundCounts counts_from(const nlohmann::json& j);

std::vector<gmf::BackgroundCounts> region_counts_from(const nlohmann::json& j, int regions) {
  std::vector<gmf::BackgroundCounts> out(static_cast<std::size_t>(regions));
  for (const auto& pair : j) {
    const auto r = pair.at(0).get<std::size_t>();
    if (r >= out.size()) throw std::out_of_range("background region " + std::to_string(r));
    out[r] = counts_from(pair.at(1));
  }
  return out;
}

gmf::BackgroundCounts counts_from(const nlohmann::json& j) {
  gmf::BackgroundCounts b;
  b.rounded = j.at("rounded").get<bool>();
  for (const auto& pair : j.at("values")) b.values[pair.at(0).get<float>()] += pair.at(1).get<std::int64_t>();
  b.total = j.at("total").get<std::int64_t>();
  b.zeros = j.at("zeros").get<std::int64_t>();
  return b;
}

void save_brick(const StreamContext& c, int id, const BrickResult& r) {
  io::fault_point("brick-save");
  gmf::CheckpointMeta meta;
  meta.extra.emplace_back("brick", std::to_string(id));
  gmf::save_checkpoint(brick_path(c, id, "ply"), r.kept, meta);
  nlohmann::json log = nlohmann::json::array();
  for (const gmf::FitIteration& it : r.log) {
    log.push_back({it.round, it.iteration, it.seconds, it.loss, it.psnr_fg, it.psnr_3d, it.gaussians, it.beta});
  }
  nlohmann::json j = {{"fingerprint", c.fingerprint},
                      {"brick", id},
                      {"kept", r.count},
                      {"foreground_core", r.foreground_core},
                      {"samples", r.samples},
                      {"seconds", r.seconds},
                      {"final_beta", r.final_beta},
                      {"background", region_counts_json(r.background)},
                      {"log", log}};
  if (!r.centres.empty) j["centres"] = {r.centres.lo, r.centres.hi};
  const std::string text = j.dump() + "\n";
  io::write_file_atomic(brick_path(c, id, "json"), text.data(), text.size());
}

// The Gaussians of a finished brick: after the brick pass (`kind` "ply") or after
// the seam pass ("seam.ply"), `count` of them.
gmf::GaussianMixture load_gaussians(const StreamContext& c, int id, const char* kind, std::size_t count) {
  gmf::GaussianMixture m = gmf::load_checkpoint(brick_path(c, id, kind)).mixture;
  if (m.size() != count) {
    io::fail_input(brick_path(c, id, kind),
                   "holds " + std::to_string(m.size()) + " Gaussians, its brick record " + std::to_string(count));
  }
  return m;
}

// A finished brick's record (its Gaussians stay on disk: load_gaussians).
std::optional<BrickResult> load_brick(const StreamContext& c, int id) {
  const std::filesystem::path json_path = brick_path(c, id, "json");
  if (!std::filesystem::exists(json_path)) return std::nullopt;
  BrickResult r;
  try {
    std::ifstream in(json_path);
    const nlohmann::json j = nlohmann::json::parse(in);
    if (j.at("fingerprint").get<std::string>() != c.fingerprint || j.at("brick").get<int>() != id) {
      io::fail_input(json_path, "belongs to another fit; remove the folder or choose another -o");
    }
    r.foreground_core = j.at("foreground_core").get<std::int64_t>();
    r.samples = j.at("samples").get<std::int64_t>();
    r.seconds = j.at("seconds").get<double>();
    r.final_beta = j.at("final_beta").get<double>();
    r.background = region_counts_from(j.at("background"), c.regions.count());
    for (const auto& row : j.at("log")) {
      gmf::FitIteration it;
      it.round = row.at(0).get<int>();
      it.iteration = row.at(1).get<int>();
      it.seconds = row.at(2).get<double>();
      it.loss = row.at(3).get<double>();
      it.psnr_fg = row.at(4).get<double>();
      it.psnr_3d = row.at(5).get<double>();
      it.gaussians = row.at(6).get<int>();
      it.beta = row.at(7).get<double>();
      r.log.push_back(it);
    }
    r.count = j.at("kept").get<std::size_t>();
    if (j.contains("centres")) {
      const auto lo = j.at("centres").at(0).get<std::array<double, 3>>();
      const auto hi = j.at("centres").at(1).get<std::array<double, 3>>();
      r.centres = CentreBox::spanning(lo.data(), hi.data());
    } else if (r.count > 0) {  // a record of an earlier build: read the Gaussians once
      r.centres = centre_box(c, load_gaussians(c, id, "ply", r.count));
    }
  } catch (const nlohmann::json::exception& e) {
    io::fail_input(json_path, std::string("not a hisnegs brick record: ") + e.what());
  }
  return r;
}

// ---- the passes -------------------------------------------------------------

// Hands the heap's free pages back after a brick: glibc keeps what a brick freed in
// its per-thread arenas, and over dozens of bricks that grew the peak by half the
// planned brick (op: 128 x 1024 x 1024 under 256 MiB).
void release_free_memory() {
#if defined(__GLIBC__)
  (void)malloc_trim(0);
#endif
}

// The fit's samples of a region (its sparse grid with the brick's seed, then dropped).
gmf::SampleSet region_samples(const StreamContext& c, const io::Volume& v, const gmf::RegionFrame& rf,
                              const gmf::GmfOptions& options) {
  io::SparseGridOptions sparse = c.config->get<&AppConfig::sparse_grid>();
  sparse.background_fraction = options.background_fraction;
  sparse.seed = options.seed;
  const io::SparseGrid grid = io::build_sparse_grid(v, rf.frame.aspect(), sparse);
  return gmf::fit_samples(grid, options);
}

std::uint64_t brick_seed(const gmf::GmfOptions& gmf, int id) {
  return io::splitmix64(gmf.seed ^ (0x9e3779b97f4a7c15ull * static_cast<std::uint64_t>(id + 1)));
}

// One brick: read, count, sample, initialize with its share of K, fit, keep the
// core's. Its time: `left` shared by its core's foreground among `rest` still to fit.
BrickResult fit_brick(const StreamContext& c, const gmf::StreamBrick& b, double left, std::int64_t rest) {
  io::Stopwatch watch;
  const FitConfig& config = *c.config;
  const io::Volume v = read_region(c, b.region);
  const gmf::RegionFrame rf = gmf::region_frame(c.frame, b.region);
  const io::VoxelBox core = local_box(b.core, b.region);
  const double threshold = config.get<&AppConfig::sparse_grid>().threshold;
  const gmf::BackgroundOptions& bg = config.get<&AppConfig::background>();
  BrickResult r;
  if (bg.estimate) r.background = gmf::count_background_regions(v, bg, core, c.regions, b.region.lo);
  r.foreground_core = count_above(v, core, threshold);
  const std::int64_t foreground_region = count_above(v.voxels, threshold);
  if (foreground_region == 0 || c.foreground == 0) {
    r.seconds = watch.elapsed();
    return r;  // nothing to fit
  }
  gmf::GmfOptions options = c.gmf;
  options.seed = brick_seed(c.gmf, b.id);
  options.time_budget_s =
      c.gmf.time_budget_s == 0
          ? 0.0  // no limit: the schedule alone
          : std::max(1e-3, left * std::min(1.0, static_cast<double>(r.foreground_core) /
                                                    static_cast<double>(std::max<std::int64_t>(1, rest))));
  options.gaussians = static_cast<int>(
      std::clamp<double>(std::llround(static_cast<double>(c.gmf.gaussians) * static_cast<double>(foreground_region) /
                                      static_cast<double>(c.foreground)),
                         1.0, 1e7));
  // The brick's own background's 99.9th percentile (fit_to_checkpoint uses the stack's).
  gmf::BackgroundCounts own;
  for (const gmf::BackgroundCounts& region : r.background) own.merge(region);
  if (own.total > 0) {
    const gmf::BackgroundModel local = gmf::background_from_counts(own, bg, c.path);
    options.clone_floor = local.none() ? 0.0 : local.quantile(0.999);
  }
  const gmf::SampleSet samples = region_samples(c, v, rf, options);
  r.samples = static_cast<std::int64_t>(samples.size());
  gmf::GaussianMixture mixture = gmf::initialize_mixture(v, rf.frame, threshold, options);
  const gmf::FitResult fit = gmf::fit_mixture(v, samples, rf.frame, mixture, options);
  r.log = fit.log;
  r.final_beta = fit.final_beta;
  shift_means(mixture, rf.shift);
  for (const gmf::GaussianParams& g : mixture) {
    if (c.plan.owner(c.frame, Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2])) == b.id) r.kept.push_back(g);
  }
  r.count = r.kept.size();
  r.centres = centre_box(c, r.kept);
  r.seconds = watch.elapsed();
  return r;
}

struct SeamStats {
  std::size_t refitted = 0, held = 0;
};

// Brick b's Gaussians after refitting those reaching its shared faces with every other
// Gaussian of `held` that reaches its region held fixed (held[b]: all of b's;
// held[o]: at least o's Gaussians within b's region grown by the halo).
gmf::GaussianMixture seam_brick(const StreamContext& c, const gmf::StreamBrick& b,
                                const std::vector<gmf::GaussianMixture>& held, double beta, double seconds,
                                SeamStats& stats) {
  gmf::GaussianMixture stay, free;  // b's Gaussians that reach no shared face, and those that do
  for (const gmf::GaussianParams& g : held[static_cast<std::size_t>(b.id)]) {
    (reaches_shared_face(c.plan, c.frame, c.gmf.mahalanobis_cutoff, b, g) ? free : stay).push_back(g);
  }
  if (free.empty()) return held[static_cast<std::size_t>(b.id)];
  gmf::GaussianMixture fixed = stay;  // held: b's own that reach no shared face and every neighbour reaching b
  for (const gmf::StreamBrick& other : c.plan.bricks) {
    if (other.id == b.id) continue;
    for (const gmf::GaussianParams& g : held[static_cast<std::size_t>(other.id)]) {
      if (within(index_of(c, g), b.region, c.plan.halo)) fixed.push_back(g);
    }
  }
  const io::Volume v = read_region(c, b.region);
  const gmf::RegionFrame rf = gmf::region_frame(c.frame, b.region);
  gmf::GmfOptions options = c.gmf;
  options.seed = brick_seed(c.gmf, b.id) ^ 0x5ea4ull;
  options.optimizer = gmf::Optimizer::kAdam;
  options.densify = false;
  // Rounds as long as the fit's, each on freshly jittered samples: one long round
  // on one set of jittered samples fits that set (600 steps: 0.8 dB lower MIPs
  // than 200 on op1 in 9 bricks), as the fit's own rounds avoid.
  options.iterations_per_round = std::max(1, std::min(c.gmf.seam_iterations, c.gmf.iterations_per_round));
  options.rounds = (c.gmf.seam_iterations + options.iterations_per_round - 1) / options.iterations_per_round;
  options.max_iterations = c.gmf.seam_iterations;  // the last round may be shorter
  options.beta_start = options.beta_end = std::max(beta, 1e-6);
  options.time_budget_s = c.gmf.time_budget_s == 0 ? 0.0 : std::max(1e-3, seconds);
  options.frozen = fixed.size();
  options.prune_intensity = 0.0;  // nothing leaves in a seam pass (a faint one stays faint)
  options.measure = false;        // its log is not kept: no round measures every Gaussian
  const gmf::SampleSet samples = region_samples(c, v, rf, options);
  gmf::GaussianMixture local;
  local.reserve(fixed.size() + free.size());
  for (const auto& g : fixed) local.push_back(g);
  for (const auto& g : free) local.push_back(g);
  shift_means(local, -rf.shift);
  (void)gmf::fit_mixture(v, samples, rf.frame, local, options);
  shift_means(local, rf.shift);
  for (std::size_t k = fixed.size(); k < local.size(); ++k) stay.push_back(local[k]);
  stats.refitted += free.size();
  stats.held += fixed.size();
  return stay;
}

// Σ (f − V)² over brick b's core voxels (the model's Gaussians that reach its region).
// `local`: the model's Gaussians within b's region grown by the halo, in brick order.
double core_squared_error(const StreamContext& c, const gmf::StreamBrick& b, gmf::GaussianMixture local,
                          const gmf::RasterizeOptions& raster) {
  const io::Volume v = read_region(c, b.region);
  const gmf::RegionFrame rf = gmf::region_frame(c.frame, b.region);
  shift_means(local, -rf.shift);
  const std::vector<float> f = gmf::rasterize_mixture(local, rf.frame, raster);
  const io::VoxelBox core = local_box(b.core, b.region);
  double sse = 0;
  for (int z = core.lo[2]; z < core.hi[2]; ++z) {
    for (int y = core.lo[1]; y < core.hi[1]; ++y) {
      for (int x = core.lo[0]; x < core.hi[0]; ++x) {
        const std::size_t i = v.index(x, y, z);
        const double d = static_cast<double>(f[i]) - static_cast<double>(v.voxels[i]);
        sse += d * d;
      }
    }
  }
  return sse;
}

// Slabs of at most a quarter of what the plan leaves beside the program.
std::size_t scan_slab_bytes(const StreamContext& c) {
  const FitMemoryModel memory;
  const double spare = std::max(0.0, c.max_memory - memory.base_bytes);
  return static_cast<std::size_t>(std::clamp(spare / 4.0, 4.0 * 1048576.0, 256.0 * 1048576.0));
}

std::vector<std::int64_t> count_core_foreground(const StreamContext& c, std::size_t slab, const Job& ranks) {
  return core_foreground_counts(*c.source, c.normalization, c.plan, c.config->get<&AppConfig::sparse_grid>().threshold,
                                slab, scan_share(ranks));
}

// The statistics a resume takes from plan.json (and the bricks' foreground when
// the run that wrote it counted them). A damaged field is one line naming it; a
// core_foreground of the wrong length is dropped and the counts are taken again.
void take_plan_statistics(StreamContext& c, const nlohmann::json& plan) {
  const auto field = [&]<typename T>(const char* key, T& to, const char* what) {
    try {
      to = plan.at(key).get<T>();
    } catch (const nlohmann::json::exception&) {
      io::fail_input(c.folder / "plan.json", std::string("field '") + key + "' is missing or not " + what +
                                                 ": not a hisnegs brick plan; remove the folder or choose another -o");
    }
  };
  c.normalization.method = c.config->get<&AppConfig::volume>().normalization.method;
  field("raw_lo", c.normalization.raw_lo, "a number");
  field("raw_hi", c.normalization.raw_hi, "a number");
  field("foreground", c.foreground, "an integer");
  if (plan.contains("core_foreground")) field("core_foreground", c.core_foreground, "a list of integers");
  if (c.core_foreground.size() != c.plan.bricks.size()) c.core_foreground.clear();
}

// The normalization and foreground count: from plan.json when resuming (the same
// fingerprint), else one streaming pass, each rank reading its share of the pages
// (the counts and extremes are exact, so the same as one process's), recorded by
// rank 0 in a new plan.json. On several ranks also each brick's foreground, which
// shares the brick pass: of an 8/16-bit stack from the cores' coarse histograms
// taken in the same pass (io::cell_counts_above; only the balance of the ranks
// depends on it, not the fit), of a float32 one from one more pass, shared alike.
// Every rank calls it.
void load_or_scan_statistics(StreamContext& c, const Job& ranks, const Progress& progress) {
  const io::VolumeOptions& vo = c.config->get<&AppConfig::volume>();
  const std::optional<nlohmann::json> plan = existing_plan(c);
  const std::size_t slab = scan_slab_bytes(c);
  io::Stopwatch scan;
  if (plan && plan->contains("raw_lo")) {
    take_plan_statistics(c, *plan);
    progress.say("fit: resuming from %s (normalization %s, statistics not read again)", c.folder.c_str(),
                 c.normalization.describe().c_str());
  } else {
    const io::ScanShare share = scan_share(ranks);
    const double threshold = c.config->get<&AppConfig::sparse_grid>().threshold;
    const bool by_cell = ranks.distributed() && c.source->stored_as != io::SampleType::kFloat32;
    const io::CellGrid cores{c.plan.core, c.plan.count};
    const io::SourceStatistics stats = io::scan_statistics(*c.source, slab, share, by_cell ? &cores : nullptr);
    c.normalization = io::normalization_from(stats, vo.normalization, c.path);
    if (by_cell) {
      c.core_foreground = io::cell_counts_above(stats, c.normalization, threshold);
    } else if (ranks.distributed()) {
      c.core_foreground = count_core_foreground(c, slab, ranks);
    }
    // exact: from the histogram (8/16-bit), or the cores' exact counts, or a pass (float32 alone)
    c.foreground = ranks.distributed() && !by_cell
                       ? std::accumulate(c.core_foreground.begin(), c.core_foreground.end(), std::int64_t{0})
                       : io::count_above(*c.source, stats, c.normalization, threshold, slab);
    if (!plan && ranks.root()) write_plan(c, stats);
    progress.say("fit: statistics in one pass%s: %s, %lld foreground voxels, %s",
                 ranks.distributed() ? strf(" (%d ranks, each its share of the pages%s)", ranks.size(),
                                            by_cell ? "; each brick's foreground from its histogram" : "")
                                           .c_str()
                                     : "",
                 c.normalization.describe().c_str(), static_cast<long long>(c.foreground),
                 format_seconds(scan.elapsed()).c_str());
  }
  if (ranks.distributed() && c.core_foreground.empty()) {  // resuming a run of one process
    c.core_foreground = count_core_foreground(c, slab, ranks);
    progress.say("fit: the foreground of each brick counted in %s", format_seconds(scan.elapsed()).c_str());
  }
}

}  // namespace

namespace {

// FOLDER/rank-R.holds: the brick rank R of a launch is fitting, so that the rerun
// after a rank died can say which one it held (MPI ends the job without a word
// from the dead rank; its launcher names the rank only).
std::filesystem::path held_path(const StreamContext& c, int rank) {
  return c.folder / ("rank-" + std::to_string(rank) + ".holds");
}

// FOLDER/rank-R.stopped: written by rank R's interrupt handler (set_interrupt_note)
// when the launcher or the user stopped it; a rank with a .holds mark and none of
// these died.
std::filesystem::path stopped_path(const StreamContext& c, int rank) {
  return c.folder / ("rank-" + std::to_string(rank) + ".stopped");
}

// What this rank says if it is stopped now: `doing`, and that a rerun resumes.
void note_for_interrupt(const StreamContext& c, const Job& ranks, const std::string& doing) {
  set_interrupt_note(strf("hisnegs: rank %d of %d: stopped while %s; the finished bricks stay in %s: run the same "
                              "command again to resume",
                              ranks.rank(), ranks.size(), doing.c_str(), c.folder.c_str()),
                         stopped_path(c, ranks.rank()));
}

// Writes FOLDER/rank-R.holds: "ID SIZE" for the rerun, then the line a neighbour
// rank says if this one dies holding the brick (set_interrupt_watch).
void hold_brick(const StreamContext& c, const Job& ranks, const gmf::StreamBrick& b) {
  const std::string brick = brick_text(c, b);
  const std::string text =
      std::to_string(b.id) + " " + std::to_string(ranks.size()) + "\n" +
      strf("rank %d of %d died (killed, crashed or out of memory) while fitting ", ranks.rank(), ranks.size()) + brick +
      "\n";
  io::write_file_atomic(held_path(c, ranks.rank()), text.data(), text.size());
  note_for_interrupt(c, ranks, "fitting " + brick);
}

// Each rank watches the next: stopped by the launcher because a rank died, rank R
// names what rank R + 1 held if that one left no mark of being stopped (so one
// dead rank is named once, by the rank before it).
void watch_next_rank(const StreamContext& c, const Job& ranks) {
  const int next = (ranks.rank() + 1) % ranks.size();
  set_interrupt_watch({{held_path(c, next), stopped_path(c, next)}}, 300);
}

// Says, for each rank of a previous launch that left its mark, the unfinished brick
// it held and whether it died there (no .stopped mark: killed, crashed, out of
// memory) or was stopped (by the launcher after another rank died, or Ctrl-C), and
// removes the marks.
void say_what_stopped_ranks_held(const StreamContext& c, const std::vector<std::optional<BrickResult>>& results,
                                 const Progress& progress) {
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(c.folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (!name.starts_with("rank-") || entry.path().extension() != ".holds") continue;
    std::istringstream in(io::read_file(entry.path()));
    long long id = -1, size = 0;
    in >> id >> size;
    const std::filesystem::path stopped = std::filesystem::path(entry.path()).replace_extension(".stopped");
    const bool died = !std::filesystem::exists(stopped, ec);
    if (id >= 0 && id < static_cast<long long>(results.size()) && !results[static_cast<std::size_t>(id)]) {
      const gmf::StreamBrick& b = c.plan.bricks[static_cast<std::size_t>(id)];
      progress.say("fit: the previous run's %s of %lld %s while fitting %s; it is fitted again",
                   name.substr(0, name.size() - 6).replace(4, 1, " ").c_str(), size,
                   died ? "died (killed, crashed or out of memory)" : "was stopped", brick_text(c, b).c_str());
    }
    std::filesystem::remove(entry.path(), ec);
    std::filesystem::remove(stopped, ec);
  }
}

}  // namespace

std::vector<int> brick_ranks(const std::vector<int>& ids, int ranks, const std::function<double(int)>& weight) {
  std::vector<int> rank_of(ids.size(), 0);
  if (ranks <= 1) return rank_of;
  // Heaviest first (ties: the lower id), each to the rank with the least so far
  // (ties: the lower rank): the same on every rank, whatever order they run in.
  std::vector<std::size_t> order(ids.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::vector<double> w(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) w[i] = weight(ids[i]);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return w[a] > w[b]; });
  std::vector<double> load(static_cast<std::size_t>(ranks), 0.0);
  for (std::size_t i : order) {
    const auto least = static_cast<std::size_t>(std::min_element(load.begin(), load.end()) - load.begin());
    load[least] += w[i];
    rank_of[i] = static_cast<int>(least);
  }
  return rank_of;
}

std::vector<std::int64_t> core_foreground_counts(const io::VolumeSource& source, const io::Normalization& map,
                                                 const gmf::BrickPlan& p, double threshold, std::size_t slab,
                                                 const io::ScanShare& share) {
  std::array<std::vector<std::size_t>, 3> cell;  // per axis, each voxel's brick coordinate
  for (int a = 0; a < 3; ++a) {
    cell[a].resize(static_cast<std::size_t>(p.shape[a]));
    for (int v = 0; v < p.shape[a]; ++v) cell[a][static_cast<std::size_t>(v)] = static_cast<std::size_t>(v / p.core[a]);
  }
  const auto nx = static_cast<std::size_t>(p.count[0]), ny = static_cast<std::size_t>(p.count[1]);
  std::vector<double> counts(p.bricks.size(), 0.0);
  std::vector<float> normalized;  // ~64 Ki values at a time: the slab is the pass's only large buffer
  io::for_each_slab(source, slab, share, [&](const io::VoxelBox& box, std::span<const float> values) {
    const auto width = static_cast<std::size_t>(box.hi[0] - box.lo[0]);
    const auto height = static_cast<std::size_t>(box.hi[1] - box.lo[1]);
    const std::size_t rows = values.size() / width, group = std::max<std::size_t>(1, 65536 / width);
    for (std::size_t r0 = 0; r0 < rows; r0 += group) {
      const std::size_t r1 = std::min(rows, r0 + group);
      normalized.assign(values.begin() + static_cast<std::ptrdiff_t>(r0 * width),
                        values.begin() + static_cast<std::ptrdiff_t>(r1 * width));
      (void)io::apply_normalization(normalized, map);
      for (std::size_t r = r0; r < r1; ++r) {
        const std::size_t z = static_cast<std::size_t>(box.lo[2]) + r / height;
        const std::size_t y = static_cast<std::size_t>(box.lo[1]) + r % height;
        const std::size_t row = (cell[2][z] * ny + cell[1][y]) * nx;
        const float* v = normalized.data() + (r - r0) * width;
        for (std::size_t i = 0; i < width; ++i) {
          if (v[i] > threshold) counts[row + cell[0][static_cast<std::size_t>(box.lo[0]) + i]] += 1.0;
        }
      }
    }
  });
  if (share.shared()) share.sum(counts);  // integers below 2^53: exact
  std::vector<std::int64_t> out(counts.size());
  for (std::size_t id = 0; id < out.size(); ++id) out[id] = std::llround(counts[id]);
  return out;
}

double brick_work(double core_foreground, double core_voxels) { return core_foreground + core_voxels / 4000.0; }

double measure_work(double region_voxels, double gaussians) { return region_voxels + 2000.0 * gaussians; }

bool reaches_shared_face(const gmf::BrickPlan& p, const io::WorldFrame& frame, double cutoff, const gmf::StreamBrick& b,
                         const gmf::GaussianParams& g) {
  const Eigen::Vector3d ijk = frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
  const Eigen::Matrix3d sigma = gmf::covariance(g);
  for (int a = 0; a < 3; ++a) {
    const double extent = std::sqrt(cutoff * sigma(a, a)) / frame.voxel_size()[a];  // voxels along axis a
    const double reach = std::min(1.25 * extent + 1.0, static_cast<double>(p.halo[a]));
    if (b.cell[a] > 0 && ijk[a] - (b.core.lo[a] - 0.5) < reach) return true;
    if (b.cell[a] + 1 < p.count[a] && (b.core.hi[a] - 0.5) - ijk[a] < reach) return true;
  }
  return false;
}

std::vector<int> share_of_bricks(const std::vector<int>& todo, const std::function<double(int)>& weight, int rank,
                                 int ranks) {
  const std::vector<int> rank_of = brick_ranks(todo, ranks, weight);
  std::vector<int> mine;
  for (std::size_t i = 0; i < todo.size(); ++i) {
    if (rank_of[i] == rank) mine.push_back(todo[i]);
  }
  return mine;
}

namespace {

// Where each brick's Gaussians are, pass by pass: the bricks' records (count and
// centres after the brick pass), then the seam pass's.
struct BrickState {
  std::vector<std::size_t> count;
  std::vector<CentreBox> centres;
  const char* kind = "ply";  // the files holding them: brick_N.ply, or brick_N.seam.ply after a seam pass
};

// The Gaussians of every brick that may be within(·, box, halo) for one of `boxes`,
// read from the folder; held[id] for `full` bricks in full, for the others only
// those within (order kept).
std::vector<gmf::GaussianMixture> read_needed(const StreamContext& c, const BrickState& state,
                                              const std::vector<io::VoxelBox>& boxes, const std::vector<bool>& full) {
  std::vector<gmf::GaussianMixture> held(c.plan.bricks.size());
  for (std::size_t o = 0; o < held.size(); ++o) {
    std::vector<const io::VoxelBox*> near;
    for (const io::VoxelBox& box : boxes) {
      if (state.centres[o].meets(box, c.plan.halo)) near.push_back(&box);
    }
    if (!full[o] && near.empty()) continue;
    gmf::GaussianMixture m = load_gaussians(c, static_cast<int>(o), state.kind, state.count[o]);
    held[o] = full[o] ? std::move(m) : within_any(c, m, near);
  }
  return held;
}

void append_record(std::vector<unsigned char>& out, int id, const gmf::GaussianMixture& m) {
  const std::uint64_t head[2] = {static_cast<std::uint64_t>(id), m.size()};
  const auto* h = reinterpret_cast<const unsigned char*>(head);
  out.insert(out.end(), h, h + sizeof head);
  const auto* g = reinterpret_cast<const unsigned char*>(m.data());
  out.insert(out.end(), g, g + m.size() * sizeof(gmf::GaussianParams));
}

void apply_records(const std::vector<unsigned char>& in, std::vector<gmf::GaussianMixture>& held) {
  for (std::size_t at = 0; at < in.size();) {
    std::uint64_t head[2];
    std::memcpy(head, in.data() + at, sizeof head);
    at += sizeof head;
    gmf::GaussianMixture& m = held.at(head[0]);
    m.resize(head[1]);
    std::memcpy(static_cast<void*>(m.data()), in.data() + at, m.size() * sizeof(gmf::GaussianParams));
    at += m.size() * sizeof(gmf::GaussianParams);
  }
}

struct SeamOutcome {
  SeamStats stats;
  double exchanged = 0;  // bytes, all ranks together
};

// The rank that refits each brick in the seam pass: per colour, the colour's bricks
// shared by the Gaussians each holds.
std::vector<int> seam_ranks(const StreamContext& c, const BrickState& state, int ranks) {
  std::vector<int> rank_of(c.plan.bricks.size(), 0);
  for (int colour = 0; colour < 8; ++colour) {
    std::vector<int> of_colour;
    for (const gmf::StreamBrick& b : c.plan.bricks) {
      if (b.colour() == colour) of_colour.push_back(b.id);
    }
    const std::vector<int> r = brick_ranks(
        of_colour, ranks, [&](int id) { return 1.0 + static_cast<double>(state.count[static_cast<std::size_t>(id)]); });
    for (std::size_t i = 0; i < of_colour.size(); ++i) rank_of[static_cast<std::size_t>(of_colour[i])] = r[i];
  }
  return rank_of;
}

// Appends to to[r], for every other rank r with a brick of a later colour than
// brick `id`'s that its Gaussians can reach (`reach`: where they were and are), the
// record of those of `m` within such a brick's region (grown by the halo).
void send_to_later_neighbours(const StreamContext& c, std::size_t id, const gmf::GaussianMixture& m,
                              const CentreBox& reach, const std::vector<int>& rank_of, int me,
                              std::vector<std::vector<unsigned char>>& to) {
  const int colour = c.plan.bricks[id].colour();
  for (std::size_t r = 0; r < to.size(); ++r) {
    if (static_cast<int>(r) == me) continue;
    std::vector<const io::VoxelBox*> later;
    for (const gmf::StreamBrick& o : c.plan.bricks) {
      if (rank_of[static_cast<std::size_t>(o.id)] == static_cast<int>(r) && o.colour() > colour &&
          reach.meets(o.region, c.plan.halo)) {
        later.push_back(&o.region);
      }
    }
    if (!later.empty()) append_record(to[r], static_cast<int>(id), within_any(c, m, later));
  }
}

// Writes this rank's seam results (brick_N.seam.ply) and makes `state` the seam
// pass's on every rank: each brick's box of centres comes from the rank that
// refitted it. Sums the outcome over the ranks.
void publish_seam_results(const StreamContext& c, const std::vector<gmf::GaussianMixture>& held,
                          const std::vector<bool>& mine, const Job& ranks, BrickState& state, SeamOutcome& out) {
  const std::size_t n = held.size();
  std::vector<double> boxes(6 * n, 0.0),
      totals = {out.exchanged, static_cast<double>(out.stats.refitted), static_cast<double>(out.stats.held)};
  for (std::size_t id = 0; id < n; ++id) {
    if (!mine[id]) continue;
    gmf::CheckpointMeta meta;
    meta.extra.emplace_back("brick", std::to_string(id));
    gmf::save_checkpoint(brick_path(c, static_cast<int>(id), "seam.ply"), held[id], meta);
    const CentreBox box = centre_box(c, held[id]);
    for (int a = 0; a < 3; ++a) {
      boxes[6 * id + a] = box.lo[a];
      boxes[6 * id + 3 + a] = box.hi[a];
    }
  }
  ranks.sum_all(boxes);  // one rank gives each brick's box, the others 0: exact
  ranks.sum_all(totals);
  for (std::size_t id = 0; id < n; ++id) {
    state.centres[id] = state.count[id] == 0 ? CentreBox{} : CentreBox::spanning(&boxes[6 * id], &boxes[6 * id + 3]);
  }
  state.kind = "seam.ply";
  out.exchanged = totals[0];
  out.stats.refitted = static_cast<std::size_t>(totals[1]);
  out.stats.held = static_cast<std::size_t>(totals[2]);
}

// The seam pass, colour by colour (bricks of one colour share no face; each is
// refitted from the state before its colour). Each rank refits its share of a
// colour's bricks, then sends each refitted brick's Gaussians only to the ranks
// with a brick of a later colour they can reach, and only those that reach it.
// Every brick's result goes to brick_N.seam.ply; `state` becomes the seam pass's.
SeamOutcome seam_pass(const StreamContext& c, BrickState& state, const Job& ranks, double beta, double budget) {
  io::Stopwatch watch;
  const std::size_t n = c.plan.bricks.size();
  const std::vector<int> rank_of = seam_ranks(c, state, ranks.size());
  std::vector<bool> mine(n);
  std::vector<io::VoxelBox> my_regions;
  for (std::size_t id = 0; id < n; ++id) {
    mine[id] = rank_of[id] == ranks.rank();
    if (mine[id]) my_regions.push_back(c.plan.bricks[id].region);
  }
  std::vector<gmf::GaussianMixture> held = read_needed(c, state, my_regions, mine);
  // With a time budget, each of this rank's bricks gets the time left times its
  // share of the Gaussians of those still to refit here.
  double to_refit = 0;
  for (std::size_t id = 0; id < n; ++id) to_refit += mine[id] ? 1.0 + static_cast<double>(state.count[id]) : 0.0;
  SeamOutcome out;
  for (int colour = 0; colour < 8; ++colour) {
    std::vector<std::pair<std::size_t, gmf::GaussianMixture>> refitted;
    for (std::size_t id = 0; id < n; ++id) {
      if (!mine[id] || c.plan.bricks[id].colour() != colour) continue;
      const double share = (1.0 + static_cast<double>(state.count[id])) / std::max(1.0, to_refit);
      to_refit -= 1.0 + static_cast<double>(state.count[id]);
      const double seconds = std::max(0.0, budget - watch.elapsed()) * std::min(1.0, share);
      refitted.emplace_back(id, seam_brick(c, c.plan.bricks[id], held, beta, seconds, out.stats));
      release_free_memory();
    }
    std::vector<std::vector<unsigned char>> to(static_cast<std::size_t>(ranks.size()));
    for (auto& [id, m] : refitted) {
      held[id] = std::move(m);
      CentreBox reach = state.centres[id];
      reach.add(centre_box(c, held[id]));
      send_to_later_neighbours(c, id, held[id], reach, rank_of, ranks.rank(), to);
    }
    if (ranks.distributed()) {
      for (const auto& bytes : to) out.exchanged += static_cast<double>(bytes.size());
      for (const auto& bytes : ranks.exchange(to)) apply_records(bytes, held);
    }
  }
  publish_seam_results(c, held, mine, ranks, state, out);
  return out;
}

// The 3D PSNR's numerator: Σ (f − V)² over every core, each rank measuring its share
// of the bricks by their cost (region voxels and Gaussians: measure_work). Each
// brick's sum is the same whoever measures it; they are added in brick order.
double measure_pass(const StreamContext& c, const BrickState& state, const Job& ranks,
                    const gmf::RasterizeOptions& raster) {
  const std::size_t n = c.plan.bricks.size();
  std::vector<int> ids(n);
  for (std::size_t id = 0; id < n; ++id) ids[id] = static_cast<int>(id);
  const std::vector<int> rank_of = brick_ranks(ids, ranks.size(), [&](int id) {
    const auto b = static_cast<std::size_t>(id);
    return measure_work(static_cast<double>(c.plan.bricks[b].region.voxels()), static_cast<double>(state.count[b]));
  });
  std::vector<double> sse(n, 0.0);
  for (std::size_t id = 0; id < n; ++id) {
    if (rank_of[id] != ranks.rank()) continue;
    const gmf::StreamBrick& b = c.plan.bricks[id];
    const std::vector<gmf::GaussianMixture> near = read_needed(c, state, {b.region}, std::vector<bool>(n, false));
    gmf::GaussianMixture local;
    for (const gmf::GaussianMixture& m : near) {
      for (const gmf::GaussianParams& g : m) local.push_back(g);
    }
    sse[id] = core_squared_error(c, b, std::move(local), raster);
    release_free_memory();
  }
  ranks.sum_all(sse);
  double total = 0;
  for (double e : sse) total += e;
  return total;
}

// The checkpoint, brick after brick in brick order (never the whole model at once).
void write_checkpoint(const StreamContext& c, const BrickState& state, const std::filesystem::path& out,
                      const gmf::CheckpointMeta& meta) {
  std::size_t total = 0;
  for (std::size_t k : state.count) total += k;
  gmf::CheckpointWriter writer(out, meta, total);
  for (std::size_t id = 0; id < state.count.size(); ++id) {
    if (state.count[id] > 0) writer.append(load_gaussians(c, static_cast<int>(id), state.kind, state.count[id]));
  }
  writer.commit();
}

// The stack opened on every rank (a shared filesystem; a rank that cannot ends the
// job before any work), the plan and the fingerprint, and the opening lines.
StreamContext open_stream(const std::string& volume, const FitConfig& config, const FitPlanChoice& choice,
                          const std::filesystem::path& out, const Progress& progress) {
  const io::VolumeOptions& vo = config.get<&AppConfig::volume>();
  StreamContext c;
  c.path = volume;
  c.config = &config;
  c.gmf = config.get<&AppConfig::gmf>();
  open_on_every_rank(job(), [&] { c.source = io::open_volume_source(volume, io::stack_read_options(vo)); });
  c.frame = io::stack_frame(c.source->nx, c.source->ny, c.source->nz, c.source->spacing, vo.aspect, volume);
  c.gmf.max_scale_world = brick_max_scale(c.frame, c.gmf);
  c.plan = choice.plan;
  c.max_memory = choice.max_memory;
  c.folder = brick_folder(out);
  c.fingerprint = fingerprint_of(volume, *c.source, config, c.plan);
  c.regions = gmf::BackgroundRegions::of({c.source->nx, c.source->ny, c.source->nz},
                                        config.get<&AppConfig::background>().region_voxels);
  progress.say("fit: %s: %d x %d x %d %s (%s as float32), %s; in-memory fit would need %s of %s: bricked: %s",
               volume.c_str(), c.source->nx, c.source->ny, c.source->nz,
               std::string(io::to_string(c.source->stored_as)).c_str(),
               io::gib_text(4.0 * static_cast<double>(c.source->whole().voxels())).c_str(), c.source->format.c_str(),
               io::gib_text(choice.whole_need).c_str(), choice.memory_source.c_str(), c.plan.describe().c_str());
  if (choice.for_ranks) {
    progress.say(
        "fit: %d MPI ranks: bricks of core %d voxels, two or more per rank (the same fit as "
        "--brick-voxels %d in one process)",
        job().size(), c.plan.core[0], c.plan.core[0]);
  }
  progress.say(
      "fit: each brick keeps the Gaussians centred in its core; scales <= %g voxels (gmf.stream_scale_voxels) "
      "reach at most sqrt(%g) x that, inside the halo; planned peak %s",
      c.gmf.stream_scale_voxels, c.gmf.mahalanobis_cutoff, io::gib_text(choice.brick_need).c_str());
  return c;
}

// The bricks this rank fits of those still to fit (`todo`, `rest` foreground voxels
// in their cores): all alone; on several ranks its share, balanced by their work
// (the foreground of their cores, counted with the statistics). Returns them and
// the foreground they hold (the time budget is shared by it).
std::pair<std::vector<int>, std::int64_t> share_for_rank(const StreamContext& c, const std::vector<int>& todo,
                                                         std::int64_t rest, const Progress& progress) {
  const Job& ranks = job();
  if (!ranks.distributed()) return {todo, rest};
  const std::vector<std::int64_t>& foreground = c.core_foreground;
  const auto weight = [&](int id) {
    return brick_work(static_cast<double>(foreground[static_cast<std::size_t>(id)]),
                      static_cast<double>(c.plan.bricks[static_cast<std::size_t>(id)].core.voxels()));
  };
  std::vector<int> mine = share_of_bricks(todo, weight, ranks.rank(), ranks.size());
  double own = 0, all = 0;
  for (int id : mine) own += weight(id);
  for (int id : todo) all += weight(id);
  std::int64_t held = 0;
  for (int id : mine) held += foreground[static_cast<std::size_t>(id)];
  progress.say(
      "fit: %d ranks share %zu bricks to fit, balanced by the foreground of their cores; "
      "rank 0 fits %zu of them, %.0f%% of the work",
      ranks.size(), todo.size(), mine.size(), all > 0 ? 100.0 * own / all : 0.0);
  return {std::move(mine), held};
}

// Every brick's record after the brick pass (resumed or fitted, here or on another
// rank), and how many this rank fitted.
struct BrickPass {
  std::vector<std::optional<BrickResult>> results;
  std::size_t fitted_here = 0;
};

// The brick pass: this rank's share of the bricks not in the folder yet, each
// written to it as it finishes, within `budget` seconds of `watch`.
BrickPass brick_pass(const StreamContext& c, const io::Stopwatch& watch, double budget, const Progress& progress) {
  const Job& ranks = job();
  const std::size_t n = c.plan.bricks.size();
  BrickPass pass;
  pass.results.resize(n);
  std::vector<std::optional<BrickResult>>& results = pass.results;
  std::int64_t done_foreground = 0;
  std::vector<int> todo;
  for (std::size_t b = 0; b < n; ++b) {
    results[b] = load_brick(c, static_cast<int>(b));
    if (results[b]) done_foreground += results[b]->foreground_core;
    if (!results[b]) todo.push_back(static_cast<int>(b));
  }
  if (todo.size() < n) progress.say("fit: %zu of %zu bricks already finished", n - todo.size(), n);
  if (ranks.root()) say_what_stopped_ranks_held(c, results, progress);
  const std::pair<std::vector<int>, std::int64_t> share =
      share_for_rank(c, todo, c.foreground - done_foreground, progress);
  const std::vector<int>& mine = share.first;
  const std::int64_t rest_foreground = share.second;  // not a structured binding: clang 14 cannot capture those
  pass.fitted_here = mine.size();
  std::int64_t done_here = 0;
  if (ranks.distributed()) watch_next_rank(c, ranks);
  SequentialBricks executor;
  executor.run(mine, [&](int id) {
    const gmf::StreamBrick& b = c.plan.bricks[static_cast<std::size_t>(id)];
    if (ranks.distributed()) hold_brick(c, ranks, b);
    // Time: what is left of the brick pass, shared by the foreground still to fit.
    const double left = std::max(0.0, budget - watch.elapsed());
    BrickResult r = fit_brick(c, b, left, std::max<std::int64_t>(1, rest_foreground - done_here));
    release_free_memory();
    save_brick(c, id, r);
    r.kept = {};  // in the folder now
    done_here += r.foreground_core;
    const int rounds = r.log.empty() ? 0 : r.log.back().round + 1;
    progress.say("fit: %s: %lld samples, %zu Gaussians kept, %d rounds, beta %g, %s", brick_text(c, b).c_str(),
                 static_cast<long long>(r.samples), r.count, rounds, r.final_beta, format_seconds(r.seconds).c_str());
    results[static_cast<std::size_t>(id)] = std::move(r);
  });
  if (ranks.distributed()) {
    // Every brick is in the folder once all ranks are here.
    std::error_code ec;
    std::filesystem::remove(held_path(c, ranks.rank()), ec);
    note_for_interrupt(c, ranks, "waiting for the other ranks' bricks (its own are finished)");
    ranks.barrier();
    set_interrupt_note("");
    set_interrupt_watch({}, 0);
    for (std::size_t b = 0; b < n; ++b) {  // their records; the Gaussians stay in the folder
      if (!results[b]) results[b] = load_brick(c, static_cast<int>(b));
      if (!results[b]) throw std::runtime_error("brick " + std::to_string(b) + " is missing after the brick pass");
    }
  }
  return pass;
}

// What the bricks' records add up to: where their Gaussians are, the background
// counts and the β of the model.
struct BrickTotals {
  BrickState state;
  std::vector<gmf::BackgroundCounts> background;  // per region
  double beta = 0;                               // 0 for a sum
};

BrickTotals brick_totals(const StreamContext& c, const std::vector<std::optional<BrickResult>>& results) {
  BrickTotals t;
  t.background.resize(static_cast<std::size_t>(c.regions.count()));
  bool any_beta = false;
  for (const std::optional<BrickResult>& r : results) {
    t.state.count.push_back(r->count);
    t.state.centres.push_back(r->centres);
    for (std::size_t i = 0; i < r->background.size() && i < t.background.size(); ++i) {
      t.background[i].merge(r->background[i]);
    }
    if (r->count > 0 && r->final_beta > 0) {
      // the highest β any brick reached: a brick given little time (little foreground)
      // stops earlier in the schedule, and its few, separate Gaussians change least with β
      t.beta = std::max(t.beta, r->final_beta);
      any_beta = true;
    }
  }
  const bool softmax = c.gmf.aggregation == gmf::Aggregation::kSoftmax;
  if (!any_beta) t.beta = softmax ? c.gmf.beta_start : 0.0;
  if (!softmax) t.beta = 0.0;
  return t;
}

void say_seam_pass(const StreamContext& c, const SeamOutcome& s, double seconds, const Progress& progress) {
  const Job& ranks = job();
  if (ranks.distributed()) {
    progress.say(
        "fit: seam pass on %d ranks: %zu Gaussians reaching a shared face refitted with %zu neighbours held "
        "fixed; %.2f MiB exchanged (each refitted brick's Gaussians near a later brick, to that brick's "
        "rank), %s",
        ranks.size(), s.stats.refitted, s.stats.held, s.exchanged / 1048576.0, format_seconds(seconds).c_str());
  } else {
    progress.say(
        "fit: seam pass: %zu Gaussians reaching a shared face refitted (%d Adam steps each brick) with %zu "
        "neighbours held fixed, %s",
        s.stats.refitted, c.gmf.seam_iterations, s.stats.held, format_seconds(seconds).c_str());
  }
}

// Rank 0's outputs: the checkpoint (brick after brick) with the fit's metadata and
// background, the log, and the brick folder removed. Returns K.
std::size_t write_outputs(const StreamContext& c, const BrickTotals& totals,
                          const std::vector<std::optional<BrickResult>>& results, const std::filesystem::path& out,
                          const std::filesystem::path& log_csv, const Progress& progress) {
  const FitConfig& config = *c.config;
  gmf::CheckpointMeta meta = checkpoint_meta(c.frame, c.source->spacing, c.normalization, c.path);
  meta.extra.emplace_back("bricks", c.plan.describe());
  meta.aggregation = c.gmf.final_aggregation();
  meta.beta = totals.beta;
  const bool counted = std::any_of(totals.background.begin(), totals.background.end(),
                                   [](const gmf::BackgroundCounts& b) { return b.total > 0; });
  if (config.get<&AppConfig::background>().estimate && counted) {
    const gmf::BackgroundField field =
        gmf::background_field(totals.background, c.regions, config.get<&AppConfig::background>(), c.path);
    if (field.none()) {
      progress.say("fit: background: exactly 0 outside the neuron (%lld voxels): no floor to draw",
                   static_cast<long long>(field.merged.voxels));
    } else {
      record_background(c.frame, config, field, meta, progress);
    }
  }
  write_checkpoint(c, totals.state, out, meta);
  if (!log_csv.empty()) {
    std::ostringstream s;
    s << fit_log_csv_header() << "\n";
    for (const std::optional<BrickResult>& r : results) append_fit_log_csv(s, r->log, "");
    const std::string csv = s.str();
    io::write_file_atomic(log_csv, csv.data(), csv.size());
  }
  std::error_code ec;
  std::filesystem::remove_all(c.folder, ec);  // the checkpoint holds everything now
  std::size_t total = 0;
  for (std::size_t k : totals.state.count) total += k;
  return total;
}

FitOutcome run_streamed(const std::string& volume, const FitConfig& config, const FitPlanChoice& choice,
                        const std::filesystem::path& out, const std::filesystem::path& log_csv,
                        const Progress& progress) {
  io::Stopwatch watch;
  StreamContext c = open_stream(volume, config, choice, out, progress);
  const Job& ranks = job();
  const double total_budget = c.gmf.budget_seconds();
  // Rank 0 (the only one alone) holds the folder; the ranks make the statistics pass
  // together (or read plan.json when resuming), and none fits before rank 0 wrote it.
  std::optional<OutputFolderLock> lock;  // and the run folder's, for a run's fit
  if (ranks.root()) lock.emplace(c.folder);
  ranks.barrier();
  load_or_scan_statistics(c, ranks, ranks.root() ? progress : Progress{});
  ranks.barrier();
  if (c.foreground == 0) {
    io::fail_input(volume, "no voxel above sparse_grid.threshold " +
                               io::number_text(config.get<&AppConfig::sparse_grid>().threshold));
  }
  const std::size_t n = c.plan.bricks.size();
  const bool seam = c.gmf.seam_iterations > 0 && n > 1;
  const BrickPass pass = brick_pass(c, watch, total_budget * (seam ? 0.85 : 0.95), progress);
  BrickTotals totals = brick_totals(c, pass.results);
  if (seam) {
    io::Stopwatch seam_watch;
    const double seam_budget = std::max(0.0, total_budget * 0.95 - watch.elapsed());
    const SeamOutcome s = seam_pass(c, totals.state, ranks, totals.beta, seam_budget);
    say_seam_pass(c, s, seam_watch.elapsed(), progress);
  }
  const double fit_seconds = watch.elapsed();
  // The measuring pass: the 3D PSNR over every voxel, brick by brick, on every rank.
  io::Stopwatch measuring;
  gmf::MixtureModel report = c.gmf.model(0);
  report.beta = totals.beta;
  const double sse = measure_pass(c, totals.state, ranks, gmf::RasterizeOptions::of(report));
  const double psnr_3d = gmf::psnr_from_mse(sse / static_cast<double>(c.source->whole().voxels()));
  if (!ranks.root()) {  // rank 0 goes on alone: the checkpoint
    return FitOutcome{0, 0.0, watch.elapsed(), rank_prefix(ranks) + std::to_string(pass.fitted_here) + " bricks"};
  }
  const std::size_t total = write_outputs(c, totals, pass.results, out, log_csv, progress);
  FitOutcome outcome{total, psnr_3d, watch.elapsed(),
                     std::string("bricks: ") + std::to_string(n) + (seam ? " + seam pass" : "")};
  progress.say("fit: wrote %s: K %zu from %zu bricks, 3D PSNR %.2f dB (measured in %s), %s (fit %s)", out.c_str(),
               total, n, psnr_3d, format_seconds(measuring.elapsed()).c_str(), format_seconds(outcome.seconds).c_str(),
               format_seconds(fit_seconds).c_str());
  return outcome;
}

}  // namespace

FitOutcome fit_streamed(const std::string& volume, const FitConfig& config, const FitPlanChoice& choice,
                        const std::filesystem::path& out, const std::filesystem::path& log_csv,
                        const Progress& progress) {
  const std::filesystem::path folder = brick_folder(out);
  const bool created = !std::filesystem::exists(folder);
  try {
    return run_streamed(volume, config, choice, out, log_csv, progress);
  } catch (...) {
    if (!job().root()) throw;  // rank 0 made the folder: only it may remove it
    // A fit that fails before any brick finished leaves no folder it made (a killed
    // one cannot clean up; its folder is resumed or refused next time).
    std::error_code ec;
    bool finished = false;
    for (const auto& e : std::filesystem::directory_iterator(folder, ec)) {
      finished = finished || (e.path().extension() == ".json" && e.path().filename() != "plan.json");
    }
    if (created && !finished) std::filesystem::remove_all(folder, ec);
    throw;
  }
}

}  // namespace hisnegs::apps
