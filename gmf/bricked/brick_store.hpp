// SPDX-License-Identifier: Apache-2.0
// The brick folder of one bricked fit (OUT.bricks): plan.json (the fingerprint of
// stack, config and plan, and the statistics a resume reuses), brick_N.ply +
// brick_N.json per finished brick (the record written last: a brick is finished
// when it exists), brick_N.seam.ply after the seam pass, and the marks of MPI
// ranks (rank-R.holds, rank-R.stopped). A killed fit resumes from it; the folder is
// removed once the checkpoint is written.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "gmf/bricked/brick_plan.hpp"
#include "gmf/core/background.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/fit.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// The bounding box of a brick's Gaussian centres (continuous index): which other
// bricks' regions (grown by the halo) its Gaussians can be within, so that a rank
// reads or is sent only the bricks it needs.
struct CentreBox {
  std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  bool empty = true;
  void add(const Eigen::Vector3d& ijk);
  void add(const CentreBox& o);
  // The box from `lo` to `hi` (as recorded in a brick record or sent by a rank).
  static CentreBox spanning(const double* lo, const double* hi);
  // Whether a centre in the box may lie within `grow` voxels of `box`.
  [[nodiscard]] bool meets(const io::VoxelBox& box, const std::array<int, 3>& grow) const;
};
[[nodiscard]] CentreBox centre_box(const io::WorldFrame& frame, const GaussianMixture& m);

// What a finished brick leaves: its Gaussians (brick_N.ply) and this (brick_N.json).
struct BrickRecord {
  GaussianMixture kept;   // empty once saved: the bricks stay in the folder, not in memory
  std::size_t count = 0;  // Gaussians kept
  CentreBox centres;
  std::vector<BackgroundCounts> background;  // per region of the stack's BackgroundRegions, or empty
  std::vector<FitIteration> log;
  std::int64_t foreground_core = 0;
  std::int64_t samples = 0;
  double seconds = 0;
  double final_beta = 0;
};

// The statistics a resume takes from plan.json instead of reading the stack again.
struct PlanStatistics {
  double raw_lo = 0, raw_hi = 0;
  std::int64_t foreground = 0;
  std::vector<std::int64_t> core_foreground;  // per brick, when counted
};

// OUT.bricks: where the bricks of a fit to `out` are kept until it is written.
[[nodiscard]] std::filesystem::path brick_folder(const std::filesystem::path& out);

class BrickStore {
 public:
  // The folder of a fit whose stack, config and plan have `fingerprint`, on the
  // stack's `frame`, with `regions` background regions.
  BrickStore(std::filesystem::path folder, std::string fingerprint, const io::WorldFrame& frame, int regions);

  [[nodiscard]] const std::filesystem::path& folder() const { return folder_; }
  [[nodiscard]] const std::string& fingerprint() const { return fingerprint_; }

  // Whether plan.json exists (refused, one line, when it is of another stack,
  // config or plan, or not a plan); its statistics when it holds them (a damaged
  // field is one line naming it).
  struct Existing {
    std::optional<PlanStatistics> statistics;
  };
  [[nodiscard]] std::optional<Existing> read_plan() const;
  // Creates the folder's plan.json: the fingerprint and the statistics a resume reuses.
  void write_plan(const std::string& stack, const BrickPlan& plan, const io::Normalization& normalization,
                  const PlanStatistics& statistics, std::uint64_t voxels) const;

  void save(int id, const BrickRecord& r) const;
  // A finished brick's record (its Gaussians stay on disk: load_gaussians).
  [[nodiscard]] std::optional<BrickRecord> load(int id) const;
  // The Gaussians of a finished brick after the brick pass (`kind` "ply") or after
  // the seam pass ("seam.ply"), `count` of them.
  [[nodiscard]] GaussianMixture load_gaussians(int id, const char* kind, std::size_t count) const;
  void save_seam(int id, const GaussianMixture& m) const;
  // The checkpoint `out`, brick after brick in brick order (never the whole model
  // at once): `count[id]` Gaussians of each brick's `kind` file.
  void write_checkpoint(const std::vector<std::size_t>& count, const char* kind, const std::filesystem::path& out,
                        const CheckpointMeta& meta) const;

  // FOLDER/rank-R.holds: the brick rank R of a launch is fitting, so that the rerun
  // after a rank died can say which one it held (MPI ends the job without a word
  // from the dead rank; its launcher names the rank only).
  [[nodiscard]] std::filesystem::path held_path(int rank) const;
  // FOLDER/rank-R.stopped: written by rank R's interrupt handler when the launcher
  // or the user stopped it; a rank with a .holds mark and none of these died.
  [[nodiscard]] std::filesystem::path stopped_path(int rank) const;

 private:
  [[nodiscard]] std::filesystem::path path(int id, const char* ext) const;
  std::filesystem::path folder_;
  std::string fingerprint_;
  io::WorldFrame frame_;
  int regions_ = 1;
};

}  // namespace hisnegs::gmf
