// SPDX-License-Identifier: Apache-2.0
// The bricked fit: a stack larger than memory (or one the user asks to cut) read by
// regions through io::VolumeSource and fitted brick by brick (gmf/bricked/brick_plan.hpp),
// each brick a pure function of its region, its share of the budget K, its seed and
// the iteration schedule; then a seam pass refits the Gaussians near the faces
// between bricks with their neighbours held fixed, colour by colour; then one pass
// measures the 3D PSNR. Finished bricks go to the brick store as they finish, so a
// killed fit resumes from them.
//
// Its seams, implemented above it: the ranks (Collective: one process, or apps'
// MPI job), the brick store (the folder), a rank's runtime (what a rank says when
// it is stopped, and which rank watches which: apps' signal handlers), and the
// progress lines. It reads no config: BrickedFitSetup is all it is told. The
// in-memory fit (gmf/fit.hpp) does not pass through it. docs/user-guide.md "Stacks
// larger than memory" tells users.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gmf/bricked/brick_plan.hpp"
#include "gmf/bricked/brick_store.hpp"
#include "gmf/bricked/collective.hpp"
#include "gmf/core/background.hpp"
#include "gmf/gmf_options.hpp"
#include "io/progress.hpp"
#include "io/sparse_grid.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::gmf {

// What every brick of one fit shares, as the caller opened and planned it.
struct BrickedFitSetup {
  std::string path;                           // the stack, as messages name it
  const io::VolumeSource* source = nullptr;   // opened on every rank
  io::WorldFrame frame;                       // of the whole stack
  GmfOptions gmf;                             // max_scale_world = brick_max_scale(frame, gmf)
  io::SparseGridOptions sparse;               // threshold, band, background samples
  BackgroundOptions background;               // estimate, region_voxels
  io::NormalizationOptions normalization_options;  // how the stack is normalized (method, percentiles)
  BrickPlan plan;
  BackgroundRegions regions;  // of the stack's background (background.region_voxels); the store's records use it
  double max_memory = 0;      // bytes: the scans' slabs are a share of what the plan leaves
  // A warm start (world coordinates of the stack): each brick starts from its
  // Gaussians centred in the brick's region (warm_start_mixture) instead of
  // gmf.init's; null: gmf.init.
  const GaussianMixture* start = nullptr;
};

// What a rank does when it is stopped from outside, and how ranks watch each other
// (apps/pipeline/interrupts.hpp). Empty functions: nothing.
struct RankRuntime {
  // The line said (and written to `marker` unless empty) if this process is stopped
  // now; an empty line clears it.
  std::function<void(std::string_view line, const std::filesystem::path& marker)> note_on_stop;
  // For each pair (said, unless): if stopped, after `wait_ms`, say the second line
  // of `said` when it exists and `unless` does not. An empty list clears it.
  std::function<void(const std::vector<std::pair<std::filesystem::path, std::filesystem::path>>& files, int wait_ms)>
      watch;
};

// Where each brick's Gaussians are: the bricks' records after the brick pass, then
// the seam pass's.
struct BrickState {
  std::vector<std::size_t> count;
  std::vector<CentreBox> centres;
  const char* kind = "ply";  // the store's files holding them: brick_N.ply, or brick_N.seam.ply after a seam pass
};

// What a bricked fit leaves (every rank; the checkpoint is the caller's, from the store).
struct BrickedFitResult {
  io::Normalization normalization;
  std::vector<BrickRecord> records;         // every brick's, by id (Gaussians in the store)
  BrickState state;                         // where the model's Gaussians are
  std::vector<BackgroundCounts> background; // per region of the setup's `regions`
  double beta = 0;                 // of the model: 0 for a sum
  std::size_t fitted_here = 0;     // bricks this rank fitted
  bool seam = false;               // a seam pass ran
  double fit_seconds = 0;          // brick and seam passes
  double psnr_3d = 0;              // over every voxel of the stack
  double measure_seconds = 0;
  [[nodiscard]] std::size_t gaussians() const;
};

// The bricked fit of `setup` into `store` on `ranks`; every rank calls it and gets
// the same result (but fitted_here). Lines go to `progress` (statistics on rank 0
// only). Throws io::InputError when no voxel is above the threshold.
[[nodiscard]] BrickedFitResult fit_bricked(const BrickedFitSetup& setup, const BrickStore& store,
                                           const Collective& ranks, const RankRuntime& runtime,
                                           const io::Progress& progress);

}  // namespace hisnegs::gmf
