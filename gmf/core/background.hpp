// SPDX-License-Identifier: Apache-2.0
// The stack's background as a maximum-intensity projection sees it: the distribution
// of the (normalized) background voxels, treated as i.i.d. noise, estimated from a
// volume and written as one text line; and the expected maximum of n draws from it,
// the MIP's floor along a ray that gathers n independent samples. Knows no camera
// and no ray marcher (splat/background_floor.hpp turns this into per-pixel floors).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "io/volume.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::gmf {

// Config section `background`: whether a fit records the stack's background for
// renders to draw its MIP floor, and how estimate_background tells background voxels
// from the neuron.
struct BackgroundOptions {
  // Estimate the stack's background and record it in the fit's checkpoint (renders
  // draw its floor); false: the checkpoint records none. A stack whose background is
  // exactly 0 records none either way.
  bool estimate = true;
  // A voxel is foreground when its normalized value is above this; background voxels
  // are those farther than guard_voxels (Chebyshev distance, in voxels) from every
  // foreground voxel, so the neuron's dim PSF halo stays out of the noise. (0, 1).
  double foreground_level = 0.2;
  int guard_voxels = 3;  // [0, 16]
  // At most this many distinct values (atoms) are kept; finer data is binned into
  // equal-width bins over [0, the largest background value]. [16, 4096].
  int max_atoms = 256;
  // A background at least this fraction exactly 0 was subtracted (as the shared
  // stacks were: op1 100.0 %, op2 99.9 %, rivulet 100.0 %); its few other voxels are
  // remnants of structure, not a noise floor, so the model is none. Raw stacks are
  // far below (op1 with the noise recipe: 55 %). (0, 1].
  double subtracted_zero_fraction = 0.99;
  // The background is estimated per region: the stack's index box split into equal
  // parts of about this many voxels a side (at most kMaxRegionsPerAxis a side), each
  // with its own distribution, so tiles, raw and subtracted parts, and regions of a
  // brain each draw their own floor. 0: one distribution for the whole stack.
  // 0 or [16, 65536].
  int region_voxels = 128;
  void validate() const;  // throws io::InputError naming the field
  template <class V>
  void visit(V&& v) {
    v("estimate", estimate);
    v("foreground_level", foreground_level);
    v("guard_voxels", guard_voxels);
    v("max_atoms", max_atoms);
    v("subtracted_zero_fraction", subtracted_zero_fraction);
    v("region_voxels", region_voxels);
  }
};

// A discrete distribution of background values (atoms in normalized intensity with
// their cumulative probabilities) and how many independent samples a ray through the
// stack gathers per voxel of path (index-space length; calibrated against the ray
// marcher by splat::calibrate_background). No atoms: no background (the floor is 0).
struct BackgroundModel {
  std::vector<double> values;      // increasing, >= 0
  std::vector<double> cdf;         // P(X <= values[i]), increasing, last = 1
  double samples_per_voxel = 1.0;  // c > 0: a ray crossing L voxels gathers c L samples
  std::int64_t voxels = 0;         // how many background voxels the estimate rests on

  // True when there is nothing to draw: no atoms, or every background voxel is 0.
  [[nodiscard]] bool none() const;
  // E[max of n i.i.d. draws] = Σ_i v_i (F_i^n − F_{i−1}^n), for real n >= 1 (n < 1
  // is taken as 1); 0 when none().
  [[nodiscard]] double expected_max(double n) const;
  [[nodiscard]] double mean() const;
  // The value at cumulative probability p (the smallest atom with F >= p).
  [[nodiscard]] double quantile(double p) const;

  // "c N v_1 F_1 ... v_N F_N" (shortest round-trip doubles); parse() reads it back
  // and throws io::InputError("SOURCE: background: problem") for anything else.
  [[nodiscard]] std::string text() const;
  [[nodiscard]] static BackgroundModel parse(std::string_view text, const std::string& source);
  void validate(const std::string& source) const;  // the rules parse() checks

  friend bool operator==(const BackgroundModel&, const BackgroundModel&) = default;
};

// The distribution of `volume`'s background voxels (normalized volume, values in
// [0, 1]) as BackgroundOptions defines them; samples_per_voxel is left at 1 for the
// calibration. A stack whose background is exactly 0, or at least
// subtracted_zero_fraction of it, gives atoms {0} (none()).
// Throws io::InputError naming volume.source when no voxel is background.
[[nodiscard]] BackgroundModel estimate_background(const io::Volume& volume, const BackgroundOptions& options = {});

// The histogram estimate_background rests on, counted piecewise: the background
// voxels of `volume` inside `box` (index space of `volume`; the foreground mask and
// its guard still see all of `volume`, so a brick's halo supplies the guard at its
// core's faces). Counts of bricks whose boxes tile a stack merge into the stack's.
struct BackgroundCounts {
  std::map<float, std::int64_t> values;  // count of every distinct value (at most kMaxValues)
  std::int64_t total = 0, zeros = 0;
  // Past kMaxValues distinct values (float32 stacks), values are rounded to a grid
  // of 1/kMaxValues over [0, 1] (normalized) before counting.
  static constexpr std::size_t kMaxValues = 65536;
  bool rounded = false;
  void add(float v, std::int64_t n = 1);
  [[nodiscard]] static float round(float v);
  void merge(const BackgroundCounts& other);
};
[[nodiscard]] BackgroundCounts count_background(const io::Volume& volume, const BackgroundOptions& options,
                                                const io::VoxelBox& box);
// The model of the counted voxels (as estimate_background describes it); throws
// io::InputError naming `source` when nothing was counted.
[[nodiscard]] BackgroundModel background_from_counts(const BackgroundCounts& counts, const BackgroundOptions& options,
                                                     const std::string& source);

// How the background's regions split a stack of `shape` (nx, ny, nz) voxels: `cells`
// parts per axis, part k of an axis of n voxels covering [n k / cells, n (k + 1) / cells).
// Regions are numbered x fastest.
struct BackgroundRegions {
  static constexpr int kMaxPerAxis = 8;
  std::array<int, 3> shape{1, 1, 1};
  std::array<int, 3> cells{1, 1, 1};
  // The split of `shape` into parts of about region_voxels a side (ceil(n /
  // region_voxels) per axis, at most kMaxPerAxis); one region when region_voxels is 0.
  [[nodiscard]] static BackgroundRegions of(const std::array<int, 3>& shape, int region_voxels);
  [[nodiscard]] int count() const { return cells[0] * cells[1] * cells[2]; }
  [[nodiscard]] int edge(int axis, int k) const {
    return static_cast<int>(static_cast<std::int64_t>(shape[axis]) * k / cells[axis]);
  }
  [[nodiscard]] io::VoxelBox box(int region) const;
  [[nodiscard]] int cell_of(int axis, int voxel) const;  // the part of that axis holding voxel
  friend bool operator==(const BackgroundRegions&, const BackgroundRegions&) = default;
};

// The background of a stack by region: the distribution of the whole stack
// (`merged`, what one region would give) and, when there are several regions, one
// per region. A region resting on fewer than kMinVoxels background voxels (the
// neuron fills it) takes `merged`.
struct BackgroundField {
  static constexpr std::int64_t kMinVoxels = 4096;
  BackgroundRegions regions;
  BackgroundModel merged;
  std::vector<BackgroundModel> models;  // regions.count() of them, or empty: `merged` everywhere
  [[nodiscard]] bool regional() const { return !models.empty(); }
  // Nothing to draw anywhere.
  [[nodiscard]] bool none() const;
  // The model of region r (merged when not regional()).
  [[nodiscard]] const BackgroundModel& at(int r) const {
    return regional() ? models[static_cast<std::size_t>(r)] : merged;
  }
  // What the regions hold, as the fit's line and `info` say it.
  struct Summary {
    int subtracted = 0;            // regions with no floor (their background is 0)
    int merged = 0;                // regions that took the merged model (too few voxels of their own)
    double p99_lo = 1.0, p99_hi = 0.0;  // the range of the others' 99th percentiles (lo > hi: none)
  };
  [[nodiscard]] Summary summary() const;
};

// The background counts of `volume`'s voxels inside `box` (index space of `volume`,
// as count_background), split by the region of `regions` each lies in; `volume`'s
// voxel (0, 0, 0) is the stack's voxel `origin`. One entry per region (empty for
// the regions `box` does not reach).
[[nodiscard]] std::vector<BackgroundCounts> count_background_regions(const io::Volume& volume,
                                                                     const BackgroundOptions& options,
                                                                     const io::VoxelBox& box,
                                                                     const BackgroundRegions& regions,
                                                                     const std::array<int, 3>& origin);
// The field of per-region counts (as count_background_regions, merged over the
// bricks of a stack). Throws io::InputError naming `source` when nothing was counted.
[[nodiscard]] BackgroundField background_field(const std::vector<BackgroundCounts>& counts,
                                               const BackgroundRegions& regions, const BackgroundOptions& options,
                                               const std::string& source);
// estimate_background by region (options.region_voxels).
[[nodiscard]] BackgroundField estimate_background_field(const io::Volume& volume, const BackgroundOptions& options = {});

}  // namespace hisnegs::gmf
