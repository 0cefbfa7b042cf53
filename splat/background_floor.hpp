// SPDX-License-Identifier: Apache-2.0
// The floor of a MIP of the stack's background noise, per pixel: a ray that crosses
// L voxels of the stack (index-space length of its chord through the box) gathers
// about c L independent samples of the background (gmf::BackgroundModel), and its MIP
// is their expected maximum. Also the calibration of c against the ray marcher that
// makes the ground truth, on a noise-only volume drawn from the model. The splat
// renderer takes the floor as one more term per pixel (SplatSettings::floor).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/background.hpp"
#include "io/volume.hpp"
#include "splat/camera.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

// E[max of n] of `model` on a grid of n, interpolated in log n: what a floor image
// evaluates per pixel (a pixel costs a lookup, not a sum over the atoms).
class FloorTable {
 public:
  FloorTable() = default;
  explicit FloorTable(const gmf::BackgroundModel& model);
  // E[max of model.samples_per_voxel × voxels], within 1e-4 relative of the exact sum.
  [[nodiscard]] double at_voxels(double voxels) const;
  [[nodiscard]] bool none() const { return values_.empty(); }
  // The table itself (what the viewer page interpolates on the GPU): E[max of n] at
  // n = 2^(i / points_per_octave()), i = 0, 1, ...
  [[nodiscard]] const std::vector<double>& values() const { return values_; }
  [[nodiscard]] static int points_per_octave();
  [[nodiscard]] double samples_per_voxel() const { return samples_per_voxel_; }

 private:
  double samples_per_voxel_ = 1.0;
  std::vector<double> values_;  // E[max of n] at n = 2^(i / kPerOctave), i = 0, 1, ...
};

// The index-space length (in voxels) of the chord of the ray origin + t dir (t >= 0,
// dir a unit world vector) through `frame`'s box; 0 when it misses.
[[nodiscard]] double box_path_voxels(const io::WorldFrame& frame, const Eigen::Vector3d& origin,
                                     const Eigen::Vector3d& dir);

// The floor image of one camera (K.height × K.width, row-major, the splat renderer's
// pixel centres): E[max of c L(pixel)]; all 0 when the model is none() or the ray
// misses the box. Parallel over rows.
[[nodiscard]] std::vector<float> background_floor(const FloorTable& table, const io::WorldFrame& frame,
                                                  const Intrinsics& K, const CameraView& view);

// The floor of a background that varies by region (gmf::BackgroundField): a ray
// gathers c L_j samples in each region j it crosses (L_j its index-space chord
// there), so its maximum has the CDF Π_j F_j(v)^(c L_j), and the floor is its
// mean. The regions' CDFs are tabled on one grid of kLevels values over [0, the
// largest atom]; the mean takes each grid interval's midpoint (within half an
// interval, top / 1022, of the exact sum).
class RegionFloor {
 public:
  static constexpr int kLevels = 512;
  RegionFloor() = default;
  RegionFloor(const gmf::BackgroundField& field, const io::WorldFrame& frame);
  [[nodiscard]] bool none() const { return log_cdf_.empty(); }
  // The floor of the ray origin + t dir (t >= 0, dir a unit world vector); 0 when it
  // misses the box.
  [[nodiscard]] double at(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const;
  // What the viewer page evaluates the same way: the regions, c, the values m_i the
  // mean gives each interval (m_0 = 0, m_i the midpoint of [v_(i-1), v_i]) and, per
  // region (x fastest), ln F_j(v_i) for i = 0 .. kLevels-1 (-1e30 for F = 0).
  [[nodiscard]] const gmf::BackgroundRegions& regions() const { return regions_; }
  [[nodiscard]] double samples_per_voxel() const { return samples_per_voxel_; }
  [[nodiscard]] const std::vector<double>& levels() const { return levels_; }
  [[nodiscard]] const std::vector<float>& log_cdf() const { return log_cdf_; }

 private:
  gmf::BackgroundRegions regions_;
  io::WorldFrame frame_;
  double samples_per_voxel_ = 1.0;
  std::vector<double> levels_;
  std::vector<float> log_cdf_;  // regions_.count() rows of kLevels
};

// The floors of one model: its background's FloorTable in its stack's frame, or a
// RegionFloor when its background varies by region. Empty (none()) when there is
// nothing to draw; then every call gives an empty image.
class BackgroundFloors {
 public:
  BackgroundFloors() = default;
  BackgroundFloors(const gmf::BackgroundModel& model, const io::WorldFrame& frame);
  BackgroundFloors(const gmf::BackgroundField& field, const io::WorldFrame& frame);
  [[nodiscard]] bool none() const { return table_.none() && regional_.none(); }
  [[nodiscard]] bool regional() const { return !regional_.none(); }
  // background_floor of this camera, or empty when none().
  [[nodiscard]] std::vector<float> operator()(const Intrinsics& K, const CameraView& view) const;
  [[nodiscard]] const FloorTable& table() const { return table_; }               // when !regional()
  [[nodiscard]] const RegionFloor& regional_floor() const { return regional_; }  // when regional()
  [[nodiscard]] const io::WorldFrame& frame() const { return frame_; }

 private:
  FloorTable table_;
  RegionFloor regional_;
  io::WorldFrame frame_;
};

// The floors a checkpoint's renders draw: its recorded background in the frame of
// its stack (volume_shape and aspect), when `draw` (SplatOptions::background) and the
// checkpoint has both; else none. Throws io::InputError naming `source` for a
// background line that does not parse.
[[nodiscard]] BackgroundFloors floors_of(const gmf::CheckpointMeta& meta, const std::string& source, bool draw);

// What calibrate_background measured: c, and how well E[max of c L] matches the
// marcher's mean MIP of noise over the chords it saw.
struct FloorCalibration {
  double samples_per_voxel = 1.0;
  double worst_relative_error = 0.0;  // over path-length bins with enough rays
  int rays = 0;
};

// Turns a model of the stack's background voxels (gmf::estimate_background) into one
// of what a ray samples: builds a noise-only volume of voxels drawn i.i.d. from
// `model`, with `frame`'s voxel spacing and at most 64 voxels a side; replaces the
// atoms by the distribution of its trilinear samples at random points (interpolation
// thins the tail the MIP sees: with the voxels' own distribution no c fits, 29 %
// off); ray-marches it (with `options`, as `gt` does) from 24 orbit cameras; and
// sets samples_per_voxel to the c whose E[max of c L] best matches the mean MIP per
// chord-length bin (relative least squares). Deterministic for a seed. A none()
// model is left as it is.
FloorCalibration calibrate_background(gmf::BackgroundModel& model, const io::WorldFrame& frame,
                                      const RaymarchOptions& options, std::uint64_t seed = 1);
// The same for a field: c is calibrated on the merged model (or, when that is
// none(), on the region resting on the most voxels) and shared by every region;
// each region's model becomes the distribution of trilinear samples of noise drawn
// from it, as above.
FloorCalibration calibrate_background(gmf::BackgroundField& field, const io::WorldFrame& frame,
                                      const RaymarchOptions& options, std::uint64_t seed = 1);

}  // namespace hisnegs::splat
