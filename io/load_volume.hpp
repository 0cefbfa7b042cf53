// SPDX-License-Identifier: Apache-2.0
// From a stack's path (TIFF or HDF5, io/stack_file.hpp) to a normalized,
// aspect-corrected volume in one call, driven by the `volume` config section.
// Composes stack_file and volume; adds no math.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "io/config.hpp"
#include "io/volume.hpp"

namespace hisnegs::io {

// Config section `volume`.
struct VolumeOptions {
  NormalizationOptions normalization;         // method: minmax | percentile, percentile_lo/hi in %
  AspectMode aspect = AspectMode::kPhysical;  // physical | shape (report Eq. 9)
  std::vector<double> spacing_um;             // [] = from the file; else [sx, sy, sz] µm, each > 0
  int channel = -1;                           // channel of multi-channel files, -1 = none (error if needed)
  std::string dataset;                        // HDF5: the dataset's path, "" = the only stack in the file
  int timepoint = -1;                         // HDF5 time series: the time point, -1 = none (error if needed)
  int level = 0;                              // OME-Zarr: the multiscale level (0: full resolution)
  double foreground_threshold = 0.2;          // relative level for the "foreground fraction" statistic, (0, 1)

  void validate() const;  // throws InputError("volume.FIELD = VALUE: rule")
  template <class V>
  void visit(V&& v) {
    v("normalization", normalization.method,
      EnumNames<NormalizationMethod>{{"minmax", NormalizationMethod::kMinMax},
                                     {"percentile", NormalizationMethod::kPercentile}});
    v("percentile_lo", normalization.percentile_lo);
    v("percentile_hi", normalization.percentile_hi);
    v("aspect", aspect, EnumNames<AspectMode>{{"physical", AspectMode::kPhysical}, {"shape", AspectMode::kShape}});
    v("spacing_um", spacing_um);
    v("channel", channel);
    v("dataset", dataset);
    v("timepoint", timepoint);
    v("level", level);
    v("foreground_threshold", foreground_threshold);
  }
};

struct TiffReadOptions;
struct StackReadOptions;
// The TIFF reader's view of `options` (channel, spacing override).
TiffReadOptions tiff_read_options(const VolumeOptions& options);
// Any stack reader's view of `options` (also the HDF5 dataset and time point).
StackReadOptions stack_read_options(const VolumeOptions& options);

struct LoadedVolume {
  Volume volume;     // normalized to [0, 1]
  WorldFrame frame;  // CONVENTIONS index <-> world map with the aspect scales
};

// The largest ratio of voxel sizes (and of the box's edge lengths) hisnegs takes:
// beyond it the world frame is degenerate in float and OpenVDB's transforms singular.
inline constexpr double kMaxSpacingRatio = 1e4;

// The world frame of a stack of this shape and spacing (the aspect scales of `mode`);
// throws InputError naming `path` when its edges differ by more than kMaxSpacingRatio.
[[nodiscard]] WorldFrame stack_frame(int nx, int ny, int nz, const VoxelSpacing& spacing, AspectMode mode,
                                     const std::filesystem::path& path);

// Reads the stack at `path` (TIFF or HDF5, io/stack_file.hpp), normalizes it and computes its world frame.
// Throws InputError naming the file for any bad input (also a voxel size or box
// whose edges differ by more than kMaxSpacingRatio).

LoadedVolume load_volume(const std::filesystem::path& path, const VolumeOptions& options);

// The same for a stack already in memory (raw values, e.g. a numpy array): normalized
// (which refuses NaN/Inf naming the voxel and raw.source) and framed as load_volume
// does; `origin` names it in the other errors. Its spacing is
// options.spacing_um when given, else raw.spacing.
LoadedVolume prepare_volume(Volume raw, const VolumeOptions& options, const std::filesystem::path& origin);

}  // namespace hisnegs::io
