// SPDX-License-Identifier: Apache-2.0
// The streamed brick fit: a stack larger than memory (or one the user asks to cut)
// read by regions through io::VolumeSource and fitted brick by brick
// (gmf/brick_plan.hpp), each brick a pure function of its region, its share of the
// budget K, its seed and the iteration schedule; then a seam pass refits the
// Gaussians near the faces between bricks with their neighbours held fixed, colour
// by colour; then one pass measures the 3D PSNR. Finished bricks are written to
// OUT.bricks/ as they finish, so a killed fit resumes from them; the folder is
// removed once the checkpoint is written. docs/user-guide.md "Stacks larger than
// memory" tells users; docs/architecture.md where the pieces are.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "apps/pipeline/fit_stage.hpp"
#include "gmf/brick_plan.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::apps {

// The fit's peak memory as a function of what it holds at once: a base (the
// program, its libraries and thread pools), bytes per voxel of the volume or brick
// region in memory (float32 voxels, the foreground mask, the sparse grid, the samples,
// the block index) and bytes per Gaussian of the whole model. Measured with
// /usr/bin/time -v on this repository's stacks (docs/benchmarks.md "Stacks larger
// than memory"); a model, not a promise: the limit is planned with it.
struct FitMemoryModel {
  double base_bytes = 112.0 * 1048576.0;
  double bytes_per_voxel = 16.0;
  double bytes_per_gaussian = 160.0;
  [[nodiscard]] double need(std::size_t voxels, std::size_t gaussians) const {
    return base_bytes + bytes_per_voxel * static_cast<double>(voxels) +
           bytes_per_gaussian * static_cast<double>(gaussians);
  }
};

// The largest brick core for a stack of `shape` (x, y, z) whose `need(core)` is at
// most `bytes`: the stack's longest side, then shrinking by a quarter to multiples of
// 16 voxels, never below `smallest` (where it stops when nothing fits: the caller
// refuses).
[[nodiscard]] int largest_core(const std::array<int, 3>& shape, int smallest, double bytes,
                               const std::function<double(int)>& need);

// How a fit of a stack of `shape` (x, y, z) runs under gmf.max_memory.
struct FitPlanChoice {
  double max_memory = 0;       // bytes
  std::string memory_source;   // "gmf.max_memory" or "auto: half of 23.4 GiB of RAM"
  double whole_need = 0;       // the in-memory fit's need (FitMemoryModel)
  bool bricked = false;        // false: today's in-memory fit
  gmf::BrickPlan plan;         // when bricked
  double brick_need = 0;       // the largest brick's need
  bool for_ranks = false;      // bricks chosen to share among MPI ranks (the stack fits)
};
// With `ranks` > 1 (an MPI launch) the fit is always bricked: without
// gmf.stream_brick_voxels, in bricks small enough for two per rank at least.
// Throws io::InputError("gmf.max_memory = X: ...") when not even the smallest brick
// fits (naming what it needs), or when gmf.max_memory does not parse.
[[nodiscard]] FitPlanChoice choose_fit_plan(const std::array<int, 3>& shape, const io::WorldFrame& frame,
                                            const gmf::GmfOptions& gmf, const FitMemoryModel& memory = {},
                                            int ranks = 1);

// Runs the jobs of a set of bricks: the place where bricks are scheduled (one after
// another here, each using every core; the MPI driver assigns them to ranks). Each
// job is independent of the others' order.
class BrickExecutor {
 public:
  virtual ~BrickExecutor() = default;
  virtual void run(const std::vector<int>& bricks, const std::function<void(int)>& job) = 0;
};
class SequentialBricks final : public BrickExecutor {
 public:
  void run(const std::vector<int>& bricks, const std::function<void(int)>& job) override {
    for (int b : bricks) job(b);
  }
};

// The rank (of `ranks`) that takes each of `ids`: heaviest by `weight` first, each
// to the rank with the least weight so far; deterministic, all 0 alone.
[[nodiscard]] std::vector<int> brick_ranks(const std::vector<int>& ids, int ranks,
                                           const std::function<double(int)>& weight);
// The bricks of `todo` (ids into a plan's bricks) that `rank` of `ranks` fits, shared
// by `weight` (brick_ranks); all of them alone.
[[nodiscard]] std::vector<int> share_of_bricks(const std::vector<int>& todo, const std::function<double(int)>& weight,
                                               int rank, int ranks);
// What fitting a brick costs, in foreground voxels: those of its core plus its core's
// reading (a voxel read and sampled costs about 1/4000 of a foreground voxel fitted:
// 0.37 µs against ~1.4 ms on one core, docs/benchmarks.md "Several MPI ranks").
[[nodiscard]] double brick_work(double core_foreground, double core_voxels);
// The foreground voxels (above `threshold` once normalized by `map`) of every
// brick's core of plan `p`, by brick id, from one pass of slabs of pages (this
// part's share when shared; the exact counts summed). What the ranks share the
// brick pass by: a brick's own region read would cost more (a region of a striped
// or tiled file decodes whole strips or tiles).
[[nodiscard]] std::vector<std::int64_t> core_foreground_counts(const io::VolumeSource& source,
                                                               const io::Normalization& map, const gmf::BrickPlan& p,
                                                               double threshold, std::size_t slab,
                                                               const io::ScanShare& share = {});
// What measuring a brick's 3D error costs, in voxels: its region's (read, rendered
// and compared) plus its Gaussians' (a Gaussian rendered costs about 2,000 voxels:
// ~20 µs against ~8 ns on one core, from the measuring passes of op1 and the
// largest stack, docs/benchmarks.md "Several MPI ranks").
[[nodiscard]] double measure_work(double region_voxels, double gaussians);
// True when g's support (dᵀΣ⁻¹d <= `cutoff`: along axis a it extends sqrt(δ Σ_aa))
// reaches a face of brick b's core that another brick of `p` shares, with a margin
// for one round's growth (x 1.25) and a voxel, never beyond the halo: the Gaussians
// the seam pass refits. Two Gaussians of neighbouring bricks whose supports overlap
// have one of them reaching across the face between them (the overlap lies on one
// side of it), and that one is refitted with the other held; a Gaussian whose
// support stays inside its core meets the neighbour's only there.
[[nodiscard]] bool reaches_shared_face(const gmf::BrickPlan& p, const io::WorldFrame& frame, double cutoff,
                                       const gmf::StreamBrick& b, const gmf::GaussianParams& g);

// The streamed fit of `volume` to the checkpoint `out` (and the log `log_csv` unless
// empty), with `choice` from choose_fit_plan (bricked). Same lines, checkpoint
// metadata and outcome as fit_to_checkpoint.
FitOutcome fit_streamed(const std::string& volume, const FitConfig& config, const FitPlanChoice& choice,
                        const std::filesystem::path& out, const std::filesystem::path& log_csv,
                        const Progress& progress);

// OUT.bricks: where the bricks of a fit to `out` are kept until it is written.
[[nodiscard]] std::filesystem::path brick_folder(const std::filesystem::path& out);

}  // namespace hisnegs::apps
