// SPDX-License-Identifier: Apache-2.0
// fit_bricked: statistics, the brick pass, the seam pass (with the exchange between
// ranks) and the measuring pass, through the brick store.
#include "gmf/bricked/bricked_fit.hpp"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numeric>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "gmf/bricked/memory_plan.hpp"
#include "gmf/bricked/schedule.hpp"
#include "gmf/core/psnr.hpp"
#include "gmf/core/rasterize.hpp"
#include "gmf/fit.hpp"
#include "gmf/init.hpp"
#include "gmf/samples.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/fault_injection.hpp"
#include "io/hash.hpp"
#include "io/text.hpp"
#include "io/timer.hpp"

namespace hisnegs::gmf {

std::size_t BrickedFitResult::gaussians() const {
  std::size_t total = 0;
  for (std::size_t k : state.count) total += k;
  return total;
}

namespace {

using io::format_seconds;
using io::strf;

// What every brick of one fit shares: the setup, the seams and the statistics.
struct StreamContext : BrickedFitSetup {
  const BrickStore* store = nullptr;
  const Collective* ranks = nullptr;
  const RankRuntime* runtime = nullptr;
  io::Normalization normalization;
  std::int64_t foreground = 0;                // voxels above sparse.threshold, whole stack
  std::vector<std::int64_t> core_foreground;  // per brick (its core); counted on several ranks only
};

void say_on_stop(const StreamContext& c, std::string_view line, const std::filesystem::path& marker) {
  if (c.runtime->note_on_stop) c.runtime->note_on_stop(line, marker);
}

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

void shift_means(GaussianMixture& m, const Eigen::Vector3d& shift) {
  for (GaussianParams& g : m) {
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(static_cast<double>(g.mean[a]) + shift[a]);
  }
}


Eigen::Vector3d index_of(const StreamContext& c, const GaussianParams& g) {
  return c.frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
}

// True when the centre (continuous index) lies within `halo` of `box` grown by `grow` voxels.
bool within(const Eigen::Vector3d& ijk, const io::VoxelBox& box, const std::array<int, 3>& grow) {
  for (int a = 0; a < 3; ++a) {
    if (ijk[a] < box.lo[a] - grow[a] - 0.5 || ijk[a] >= box.hi[a] + grow[a] - 0.5) return false;
  }
  return true;
}


// The Gaussians of `m` within(·, box, halo) of one of `boxes`, in order.
GaussianMixture within_any(const StreamContext& c, const GaussianMixture& m,
                                const std::vector<const io::VoxelBox*>& boxes) {
  GaussianMixture near;
  for (const GaussianParams& g : m) {
    const Eigen::Vector3d ijk = index_of(c, g);
    if (std::any_of(boxes.begin(), boxes.end(),
                    [&](const io::VoxelBox* box) { return within(ijk, *box, c.plan.halo); })) {
      near.push_back(g);
    }
  }
  return near;
}


// "brick 6/16 (cell 1,1,0)": how every line names a brick.
std::string brick_text(const StreamContext& c, const StreamBrick& b) {
  return strf("brick %d/%zu (cell %d,%d,%d)", b.id + 1, c.plan.bricks.size(), b.cell[0], b.cell[1], b.cell[2]);
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
SampleSet region_samples(const StreamContext& c, const io::Volume& v, const RegionFrame& rf,
                              const GmfOptions& options) {
  io::SparseGridOptions sparse = c.sparse;
  sparse.background_fraction = options.background_fraction;
  sparse.seed = options.seed;
  const io::SparseGrid grid = io::build_sparse_grid(v, rf.frame.aspect(), sparse);
  return fit_samples(grid, options);
}

std::uint64_t brick_seed(const GmfOptions& gmf, int id) {
  return io::splitmix64(gmf.seed ^ (0x9e3779b97f4a7c15ull * static_cast<std::uint64_t>(id + 1)));
}

// One brick: read, count, sample, initialize with its share of K, fit, keep the
// core's. Its time: `left` shared by its core's foreground among `rest` still to fit.
BrickRecord fit_brick(const StreamContext& c, const StreamBrick& b, double left, std::int64_t rest) {
  io::Stopwatch watch;
  const io::Volume v = read_region(c, b.region);
  const RegionFrame rf = region_frame(c.frame, b.region);
  const io::VoxelBox core = local_box(b.core, b.region);
  const double threshold = c.sparse.threshold;
  const BackgroundOptions& bg = c.background;
  BrickRecord r;
  if (bg.estimate) r.background = count_background_regions(v, bg, core, c.regions, b.region.lo);
  r.foreground_core = count_above(v, core, threshold);
  const std::int64_t foreground_region = count_above(v.voxels, threshold);
  if (foreground_region == 0 || c.foreground == 0) {
    r.seconds = watch.elapsed();
    return r;  // nothing to fit
  }
  GmfOptions options = c.gmf;
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
  BackgroundCounts own;
  for (const BackgroundCounts& region : r.background) own.merge(region);
  if (own.total > 0) {
    const BackgroundModel local = background_from_counts(own, bg, c.path);
    options.clone_floor = local.none() ? 0.0 : local.quantile(0.999);
  }
  const SampleSet samples = region_samples(c, v, rf, options);
  r.samples = static_cast<std::int64_t>(samples.size());
  GaussianMixture mixture = c.start != nullptr ? warm_start_mixture(*c.start, rf.frame, options, rf.shift)
                                               : initialize_mixture(v, rf.frame, threshold, options);
  if (mixture.empty()) mixture = initialize_mixture(v, rf.frame, threshold, options);  // nothing of the model here
  const FitResult fit = fit_mixture(v, samples, rf.frame, mixture, options);
  r.log = fit.log;
  r.final_beta = fit.final_beta;
  shift_means(mixture, rf.shift);
  for (const GaussianParams& g : mixture) {
    if (c.plan.owner(c.frame, Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2])) == b.id) r.kept.push_back(g);
  }
  r.count = r.kept.size();
  r.centres = centre_box(c.frame, r.kept);
  r.seconds = watch.elapsed();
  return r;
}

struct SeamStats {
  std::size_t refitted = 0, held = 0;
  std::size_t left = 0;  // bricks left as the brick pass fitted them: the time budget was spent
};

// Brick b's Gaussians after refitting those reaching its shared faces with every other
// Gaussian of `held` that reaches its region held fixed (held[b]: all of b's;
// held[o]: at least o's Gaussians within b's region grown by the halo).
GaussianMixture seam_brick(const StreamContext& c, const StreamBrick& b,
                                const std::vector<GaussianMixture>& held, double beta, double seconds,
                                SeamStats& stats) {
  GaussianMixture stay, free;  // b's Gaussians that reach no shared face, and those that do
  for (const GaussianParams& g : held[static_cast<std::size_t>(b.id)]) {
    (reaches_shared_face(c.plan, c.frame, c.gmf.mahalanobis_cutoff, b, g) ? free : stay).push_back(g);
  }
  if (free.empty()) return held[static_cast<std::size_t>(b.id)];
  GaussianMixture fixed = stay;  // held: b's own that reach no shared face and every neighbour reaching b
  for (const StreamBrick& other : c.plan.bricks) {
    if (other.id == b.id) continue;
    for (const GaussianParams& g : held[static_cast<std::size_t>(other.id)]) {
      if (within(index_of(c, g), b.region, c.plan.halo)) fixed.push_back(g);
    }
  }
  const io::Volume v = read_region(c, b.region);
  const RegionFrame rf = region_frame(c.frame, b.region);
  GmfOptions options = c.gmf;
  options.seed = brick_seed(c.gmf, b.id) ^ 0x5ea4ull;
  options.optimizer = Optimizer::kAdam;
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
  const SampleSet samples = region_samples(c, v, rf, options);
  GaussianMixture local;
  local.reserve(fixed.size() + free.size());
  for (const auto& g : fixed) local.push_back(g);
  for (const auto& g : free) local.push_back(g);
  shift_means(local, -rf.shift);
  (void)fit_mixture(v, samples, rf.frame, local, options);
  shift_means(local, rf.shift);
  for (std::size_t k = fixed.size(); k < local.size(); ++k) stay.push_back(local[k]);
  stats.refitted += free.size();
  stats.held += fixed.size();
  return stay;
}

// Σ (f − V)² over brick b's core voxels (the model's Gaussians that reach its region).
// `local`: the model's Gaussians within b's region grown by the halo, in brick order.
// Only the core is read and rasterized (each voxel's value depends on its position
// and the Gaussians alone, not on the lattice around it).
double core_squared_error(const StreamContext& c, const StreamBrick& b, GaussianMixture local,
                          const RasterizeOptions& raster) {
  const io::Volume v = read_region(c, b.core);
  const RegionFrame rf = region_frame(c.frame, b.core);
  shift_means(local, -rf.shift);
  const std::vector<float> f = rasterize_mixture(local, rf.frame, raster);
  double sse = 0;
  for (std::size_t i = 0; i < f.size(); ++i) {
    const double d = static_cast<double>(f[i]) - static_cast<double>(v.voxels[i]);
    sse += d * d;
  }
  return sse;
}

// Slabs of at most a quarter of what the plan leaves beside the program.
std::size_t scan_slab_bytes(const StreamContext& c) {
  const FitMemoryModel memory;
  const double spare = std::max(0.0, c.max_memory - memory.base_bytes);
  return static_cast<std::size_t>(std::clamp(spare / 4.0, 4.0 * 1048576.0, 256.0 * 1048576.0));
}

std::vector<std::int64_t> count_core_foreground(const StreamContext& c, std::size_t slab, const Collective& ranks) {
  return core_foreground_counts(*c.source, c.normalization, c.plan, c.sparse.threshold,
                                slab, scan_share(ranks));
}

// The statistics a resume takes from plan.json (and the bricks' foreground when
// the run that wrote it counted them); a core_foreground of the wrong length is
// dropped and the counts are taken again.
void take_plan_statistics(StreamContext& c, const PlanStatistics& s) {
  c.normalization.method = c.normalization_options.method;
  c.normalization.raw_lo = s.raw_lo;
  c.normalization.raw_hi = s.raw_hi;
  c.foreground = s.foreground;
  c.core_foreground = s.core_foreground;
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
void load_or_scan_statistics(StreamContext& c, const Collective& ranks, const io::Progress& progress) {
  const std::optional<BrickStore::Existing> plan = c.store->read_plan();
  const std::size_t slab = scan_slab_bytes(c);
  io::Stopwatch scan;
  if (plan && plan->statistics) {
    take_plan_statistics(c, *plan->statistics);
    progress.say("fit: resuming from %s (normalization %s, statistics not read again)", c.store->folder().c_str(),
                 c.normalization.describe().c_str());
  } else {
    const io::ScanShare share = scan_share(ranks);
    const double threshold = c.sparse.threshold;
    const bool by_cell = ranks.distributed() && c.source->stored_as != io::SampleType::kFloat32;
    const io::CellGrid cores{c.plan.core, c.plan.count};
    const io::SourceStatistics stats = io::scan_statistics(*c.source, slab, share, by_cell ? &cores : nullptr);
    c.normalization = io::normalization_from(stats, c.normalization_options, c.path);
    if (by_cell) {
      c.core_foreground = io::cell_counts_above(stats, c.normalization, threshold);
    } else if (ranks.distributed()) {
      c.core_foreground = count_core_foreground(c, slab, ranks);
    }
    // exact: from the histogram (8/16-bit), or the cores' exact counts, or a pass (float32 alone)
    c.foreground = ranks.distributed() && !by_cell
                       ? std::accumulate(c.core_foreground.begin(), c.core_foreground.end(), std::int64_t{0})
                       : io::count_above(*c.source, stats, c.normalization, threshold, slab);
    if (!plan && ranks.root()) {
      c.store->write_plan(c.path, c.plan, c.normalization, {0, 0, c.foreground, c.core_foreground}, stats.voxels);
    }
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


// What this rank says if it is stopped now: `doing`, and that a rerun resumes.
void note_for_interrupt(const StreamContext& c, const Collective& ranks, const std::string& doing) {
  say_on_stop(c, strf("hisnegs: rank %d of %d: stopped while %s; the finished bricks stay in %s: run the same "
                              "command again to resume",
                              ranks.rank(), ranks.size(), doing.c_str(), c.store->folder().c_str()),
              c.store->stopped_path(ranks.rank()));
}

// Writes FOLDER/rank-R.holds: "ID SIZE" for the rerun (ID the brick it fits, -1
// when it fits none), then the line a neighbour rank says if this one dies while
// `doing` it (RankRuntime::watch); and the note this rank says if it is stopped.
void mark_doing(const StreamContext& c, const Collective& ranks, int id, const std::string& doing) {
  const std::string text =
      std::to_string(id) + " " + std::to_string(ranks.size()) + "\n" +
      strf("rank %d of %d died (killed, crashed or out of memory) while ", ranks.rank(), ranks.size()) + doing + "\n";
  io::write_file_atomic(c.store->held_path(ranks.rank()), text.data(), text.size());
  note_for_interrupt(c, ranks, doing);
}

void hold_brick(const StreamContext& c, const Collective& ranks, const StreamBrick& b) {
  mark_doing(c, ranks, b.id, "fitting " + brick_text(c, b));
}

// Ends this rank's marks, note and watch (the passes are over).
void end_marks(const StreamContext& c, const Collective& ranks) {
  std::error_code ec;
  std::filesystem::remove(c.store->held_path(ranks.rank()), ec);
  say_on_stop(c, "", {});
  if (c.runtime->watch) c.runtime->watch({}, 0);
}

// Each rank watches the next: stopped by the launcher because a rank died, rank R
// names what rank R + 1 held if that one left no mark of being stopped (so one
// dead rank is named once, by the rank before it).
void watch_next_rank(const StreamContext& c, const Collective& ranks) {
  const int next = (ranks.rank() + 1) % ranks.size();
  if (c.runtime->watch) c.runtime->watch({{c.store->held_path(next), c.store->stopped_path(next)}}, 300);
}

// Says, for each rank of a previous launch that left its mark, the unfinished brick
// it held and whether it died there (no .stopped mark: killed, crashed, out of
// memory) or was stopped (by the launcher after another rank died, or Ctrl-C), and
// removes the marks.
void say_what_stopped_ranks_held(const StreamContext& c, const std::vector<std::optional<BrickRecord>>& results,
                                 const io::Progress& progress) {
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(c.store->folder(), ec)) {
    const std::string name = entry.path().filename().string();
    if (!name.starts_with("rank-") || entry.path().extension() != ".holds") continue;
    std::istringstream in(io::read_file(entry.path()));
    long long id = -1, size = 0;
    in >> id >> size;
    std::string said;
    std::getline(in >> std::ws, said);
    const std::filesystem::path stopped = std::filesystem::path(entry.path()).replace_extension(".stopped");
    const bool died = !std::filesystem::exists(stopped, ec);
    if (id < 0 && died && !said.empty()) {  // it died between bricks: waiting, in the seam or measuring pass
      progress.say("fit: the previous run's %s", said.c_str());
    } else if (id >= 0 && id < static_cast<long long>(results.size()) && !results[static_cast<std::size_t>(id)]) {
      const StreamBrick& b = c.plan.bricks[static_cast<std::size_t>(id)];
      progress.say("fit: the previous run's %s of %lld %s while fitting %s; it is fitted again",
                   name.substr(0, name.size() - 6).replace(4, 1, " ").c_str(), size,
                   died ? "died (killed, crashed or out of memory)" : "was stopped", brick_text(c, b).c_str());
    }
    std::filesystem::remove(entry.path(), ec);
    std::filesystem::remove(stopped, ec);
  }
}


// The Gaussians of every brick that may be within(·, box, halo) for one of `boxes`,
// read from the folder; held[id] for `full` bricks in full, for the others only
// those within (order kept).
std::vector<GaussianMixture> read_needed(const StreamContext& c, const BrickState& state,
                                              const std::vector<io::VoxelBox>& boxes, const std::vector<bool>& full) {
  std::vector<GaussianMixture> held(c.plan.bricks.size());
  for (std::size_t o = 0; o < held.size(); ++o) {
    std::vector<const io::VoxelBox*> near;
    for (const io::VoxelBox& box : boxes) {
      if (state.centres[o].meets(box, c.plan.halo)) near.push_back(&box);
    }
    if (!full[o] && near.empty()) continue;
    GaussianMixture m = c.store->load_gaussians(static_cast<int>(o), state.kind, state.count[o]);
    held[o] = full[o] ? std::move(m) : within_any(c, m, near);
  }
  return held;
}

void append_record(std::vector<unsigned char>& out, int id, const GaussianMixture& m) {
  const std::uint64_t head[2] = {static_cast<std::uint64_t>(id), m.size()};
  const auto* h = reinterpret_cast<const unsigned char*>(head);
  out.insert(out.end(), h, h + sizeof head);
  const auto* g = reinterpret_cast<const unsigned char*>(m.data());
  out.insert(out.end(), g, g + m.size() * sizeof(GaussianParams));
}

void apply_records(const std::vector<unsigned char>& in, std::vector<GaussianMixture>& held) {
  for (std::size_t at = 0; at < in.size();) {
    std::uint64_t head[2];
    std::memcpy(head, in.data() + at, sizeof head);
    at += sizeof head;
    GaussianMixture& m = held.at(head[0]);
    m.resize(head[1]);
    std::memcpy(static_cast<void*>(m.data()), in.data() + at, m.size() * sizeof(GaussianParams));
    at += m.size() * sizeof(GaussianParams);
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
    for (const StreamBrick& b : c.plan.bricks) {
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
void send_to_later_neighbours(const StreamContext& c, std::size_t id, const GaussianMixture& m,
                              const CentreBox& reach, const std::vector<int>& rank_of, int me,
                              std::vector<std::vector<unsigned char>>& to) {
  const int colour = c.plan.bricks[id].colour();
  for (std::size_t r = 0; r < to.size(); ++r) {
    if (static_cast<int>(r) == me) continue;
    std::vector<const io::VoxelBox*> later;
    for (const StreamBrick& o : c.plan.bricks) {
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
void publish_seam_results(const StreamContext& c, const std::vector<GaussianMixture>& held,
                          const std::vector<bool>& mine, const Collective& ranks, BrickState& state, SeamOutcome& out) {
  const std::size_t n = held.size();
  std::vector<double> boxes(6 * n, 0.0),
      totals = {out.exchanged, static_cast<double>(out.stats.refitted), static_cast<double>(out.stats.held),
                static_cast<double>(out.stats.left)};
  for (std::size_t id = 0; id < n; ++id) {
    if (!mine[id]) continue;
    c.store->save_seam(static_cast<int>(id), held[id]);
    const CentreBox box = centre_box(c.frame, held[id]);
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
  out.stats.left = static_cast<std::size_t>(totals[3]);
}

// The seam pass, colour by colour (bricks of one colour share no face; each is
// refitted from the state before its colour). Each rank refits its share of a
// colour's bricks, then sends each refitted brick's Gaussians only to the ranks
// with a brick of a later colour they can reach, and only those that reach it.
// Every brick's result goes to brick_N.seam.ply; `state` becomes the seam pass's.
SeamOutcome seam_pass(const StreamContext& c, BrickState& state, const Collective& ranks, double beta, double budget) {
  io::Stopwatch watch;
  if (ranks.distributed()) mark_doing(c, ranks, -1, "refitting the seams between bricks");
  io::fault_point("seam-pass");
  const std::size_t n = c.plan.bricks.size();
  const std::vector<int> rank_of = seam_ranks(c, state, ranks.size());
  std::vector<bool> mine(n);
  std::vector<io::VoxelBox> my_regions;
  for (std::size_t id = 0; id < n; ++id) {
    mine[id] = rank_of[id] == ranks.rank();
    if (mine[id]) my_regions.push_back(c.plan.bricks[id].region);
  }
  std::vector<GaussianMixture> held = read_needed(c, state, my_regions, mine);
  // With a time budget, each of this rank's bricks gets the time left times its
  // share of the Gaussians of those still to refit here.
  double to_refit = 0;
  for (std::size_t id = 0; id < n; ++id) to_refit += mine[id] ? 1.0 + static_cast<double>(state.count[id]) : 0.0;
  SeamOutcome out;
  for (int colour = 0; colour < 8; ++colour) {
    std::vector<std::pair<std::size_t, GaussianMixture>> refitted;
    for (std::size_t id = 0; id < n; ++id) {
      if (!mine[id] || c.plan.bricks[id].colour() != colour) continue;
      const double share = (1.0 + static_cast<double>(state.count[id])) / std::max(1.0, to_refit);
      to_refit -= 1.0 + static_cast<double>(state.count[id]);
      const double left = budget - watch.elapsed();
      if (c.gmf.time_budget_s > 0 && left <= 0) {  // each refit costs its reading and sampling at least
        refitted.emplace_back(id, held[id]);
        ++out.stats.left;
        continue;
      }
      const double seconds = std::max(0.0, left) * std::min(1.0, share);
      refitted.emplace_back(id, seam_brick(c, c.plan.bricks[id], held, beta, seconds, out.stats));
      release_free_memory();
    }
    std::vector<std::vector<unsigned char>> to(static_cast<std::size_t>(ranks.size()));
    for (auto& [id, m] : refitted) {
      held[id] = std::move(m);
      CentreBox reach = state.centres[id];
      reach.add(centre_box(c.frame, held[id]));
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
double measure_pass(const StreamContext& c, const BrickState& state, const Collective& ranks,
                    const RasterizeOptions& raster) {
  const std::size_t n = c.plan.bricks.size();
  if (ranks.distributed()) mark_doing(c, ranks, -1, "measuring the 3D PSNR");
  std::vector<int> ids(n);
  for (std::size_t id = 0; id < n; ++id) ids[id] = static_cast<int>(id);
  const std::vector<int> rank_of = brick_ranks(ids, ranks.size(), [&](int id) {
    const auto b = static_cast<std::size_t>(id);
    return measure_work(static_cast<double>(c.plan.bricks[b].core.voxels()), static_cast<double>(state.count[b]));
  });
  std::vector<double> sse(n, 0.0);
  for (std::size_t id = 0; id < n; ++id) {
    if (rank_of[id] != ranks.rank()) continue;
    const StreamBrick& b = c.plan.bricks[id];
    const std::vector<GaussianMixture> near = read_needed(c, state, {b.region}, std::vector<bool>(n, false));
    GaussianMixture local;
    for (const GaussianMixture& m : near) {
      for (const GaussianParams& g : m) local.push_back(g);
    }
    sse[id] = core_squared_error(c, b, std::move(local), raster);
    release_free_memory();
  }
  ranks.sum_all(sse);
  double total = 0;
  for (double e : sse) total += e;
  return total;
}


// The bricks this rank fits of those still to fit (`todo`, `rest` foreground voxels
// in their cores): all alone; on several ranks its share, balanced by their work
// (the foreground of their cores, counted with the statistics). Returns them and
// the foreground they hold (the time budget is shared by it).
std::pair<std::vector<int>, std::int64_t> share_for_rank(const StreamContext& c, const std::vector<int>& todo,
                                                         std::int64_t rest, const io::Progress& progress) {
  const Collective& ranks = *c.ranks;
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
  std::vector<std::optional<BrickRecord>> results;
  std::size_t fitted_here = 0;
};

// The brick pass: this rank's share of the bricks not in the folder yet, each
// written to it as it finishes, within `budget` seconds of `watch`.
BrickPass brick_pass(const StreamContext& c, const io::Stopwatch& watch, double budget, const io::Progress& progress) {
  const Collective& ranks = *c.ranks;
  const std::size_t n = c.plan.bricks.size();
  BrickPass pass;
  pass.results.resize(n);
  std::vector<std::optional<BrickRecord>>& results = pass.results;
  std::int64_t done_foreground = 0;
  std::vector<int> todo;
  for (std::size_t b = 0; b < n; ++b) {
    results[b] = c.store->load(static_cast<int>(b));
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
  if (ranks.distributed()) {
    ranks.barrier();  // rank 0 has removed the previous launch's marks: this one's may start
    watch_next_rank(c, ranks);
  }
  // What a brick costs beside its fit (reading, sampling, initializing, saving),
  // measured on the bricks done so far: every brick still to do will cost it, so
  // the fits share only what is left after it (tiny bricks are mostly this).
  double overhead = 0;
  std::size_t done_bricks = 0;
  for (const int id : mine) {
    const StreamBrick& b = c.plan.bricks[static_cast<std::size_t>(id)];
    if (ranks.distributed()) hold_brick(c, ranks, b);
    // Time: what is left of the brick pass, shared by the foreground still to fit.
    const double start = watch.elapsed();
    const double still = static_cast<double>(mine.size() - done_bricks);
    const double per_brick = done_bricks == 0 ? 0.0 : overhead / static_cast<double>(done_bricks);
    const double left = std::max(0.0, budget - start - per_brick * still);
    if (c.gmf.time_budget_s > 0 && done_bricks == 1 && start + per_brick * still > budget) {
      progress.say("fit: the bricks cost %s each beside their fits: %zu more take %s, past the brick pass's share "
                   "of gmf.time_budget_s (%s); each is fitted as briefly as it can be (larger bricks cost less)",
                   format_seconds(per_brick).c_str(), mine.size() - done_bricks,
                   format_seconds(per_brick * still).c_str(), format_seconds(budget).c_str());
    }
    BrickRecord r = fit_brick(c, b, left, std::max<std::int64_t>(1, rest_foreground - done_here));
    release_free_memory();
    c.store->save(id, r);
    r.kept = {};  // in the folder now
    done_here += r.foreground_core;
    overhead += std::max(0.0, watch.elapsed() - start - (r.log.empty() ? 0.0 : r.log.back().seconds));
    ++done_bricks;
    const int rounds = r.log.empty() ? 0 : r.log.back().round + 1;
    progress.say("fit: %s: %lld samples, %zu Gaussians kept, %d rounds, beta %g, %s", brick_text(c, b).c_str(),
                 static_cast<long long>(r.samples), r.count, rounds, r.final_beta, format_seconds(r.seconds).c_str());
    results[static_cast<std::size_t>(id)] = std::move(r);
  }
  if (ranks.distributed()) {
    // Every brick is in the folder once all ranks are here.
    mark_doing(c, ranks, -1, "waiting for the other ranks' bricks (its own are finished)");
    ranks.barrier();
    for (std::size_t b = 0; b < n; ++b) {  // their records; the Gaussians stay in the folder
      if (!results[b]) results[b] = c.store->load(static_cast<int>(b));
      if (!results[b]) throw std::runtime_error("brick " + std::to_string(b) + " is missing after the brick pass");
    }
  }
  return pass;
}

// What the bricks' records add up to: where their Gaussians are, the background
// counts and the β of the model.
struct BrickTotals {
  BrickState state;
  std::vector<BackgroundCounts> background;  // per region
  double beta = 0;                               // 0 for a sum
};

BrickTotals brick_totals(const StreamContext& c, const std::vector<std::optional<BrickRecord>>& results) {
  BrickTotals t;
  t.background.resize(static_cast<std::size_t>(c.regions.count()));
  bool any_beta = false;
  for (const std::optional<BrickRecord>& r : results) {
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
  const bool softmax = c.gmf.aggregation == Aggregation::kSoftmax;
  if (!any_beta) t.beta = softmax ? c.gmf.beta_start : 0.0;
  if (!softmax) t.beta = 0.0;
  return t;
}

void say_seam_pass(const StreamContext& c, const SeamOutcome& s, double seconds, const io::Progress& progress) {
  const Collective& ranks = *c.ranks;
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
  if (s.stats.left > 0) {
    progress.say("fit: seam pass: %zu of %zu bricks left as the brick pass fitted them: the time budget "
                 "(gmf.time_budget_s %g s) was spent",
                 s.stats.left, c.plan.bricks.size(), c.gmf.time_budget_s);
  }
}


}  // namespace

BrickedFitResult fit_bricked(const BrickedFitSetup& setup, const BrickStore& store, const Collective& ranks,
                             const RankRuntime& runtime, const io::Progress& progress) {
  io::Stopwatch watch;
  StreamContext c;
  static_cast<BrickedFitSetup&>(c) = setup;
  c.store = &store;
  c.ranks = &ranks;
  c.runtime = &runtime;
  const double total_budget = c.gmf.budget_seconds();
  // The ranks make the statistics pass together (or read plan.json when resuming),
  // and none fits before rank 0 wrote it.
  load_or_scan_statistics(c, ranks, ranks.root() ? progress : io::Progress{});
  ranks.barrier();
  if (c.foreground == 0) {
    io::fail_input(c.path, "no voxel above sparse_grid.threshold " + io::number_text(c.sparse.threshold));
  }
  const std::size_t n = c.plan.bricks.size();
  BrickedFitResult result;
  result.seam = c.gmf.seam_iterations > 0 && n > 1;
  BrickPass pass = brick_pass(c, watch, total_budget * (result.seam ? 0.85 : 0.95), progress);
  BrickTotals totals = brick_totals(c, pass.results);
  const double seam_budget = std::max(0.0, total_budget * 0.95 - watch.elapsed());
  if (result.seam && c.gmf.time_budget_s > 0 && seam_budget <= 0) {
    progress.say("fit: seam pass skipped: the time budget (gmf.time_budget_s %g s) was spent", c.gmf.time_budget_s);
    result.seam = false;
  }
  if (result.seam) {
    io::Stopwatch seam_watch;
    const SeamOutcome s = seam_pass(c, totals.state, ranks, totals.beta, seam_budget);
    say_seam_pass(c, s, seam_watch.elapsed(), progress);
  }
  result.fit_seconds = watch.elapsed();
  // The measuring pass: the 3D PSNR over every voxel, brick by brick, on every rank.
  io::Stopwatch measuring;
  MixtureModel report = c.gmf.model(0);
  report.beta = totals.beta;
  const double sse = measure_pass(c, totals.state, ranks, RasterizeOptions::of(report));
  result.psnr_3d = psnr_from_mse(sse / static_cast<double>(c.source->whole().voxels()));
  result.measure_seconds = measuring.elapsed();
  if (ranks.distributed()) end_marks(c, ranks);
  result.normalization = c.normalization;
  for (std::optional<BrickRecord>& r : pass.results) result.records.push_back(std::move(*r));
  result.state = std::move(totals.state);
  result.background = std::move(totals.background);
  result.beta = totals.beta;
  result.fitted_here = pass.fitted_here;
  return result;
}

}  // namespace hisnegs::gmf
