// SPDX-License-Identifier: Apache-2.0
// What a file holds, as `hisnegs info` prints it and the Python module's
// hisnegs.info returns it: a TIFF/HDF5/BigDataViewer/Imaris stack (shape, spacing,
// intensity statistics, normalization), an OpenVDB file (its grids) or a .ply / .hgs
// checkpoint (metadata, background, parameter ranges, and against its stack the
// halos).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "io/load_volume.hpp"

namespace hisnegs::apps {

struct FileInfo {
  std::string kind;  // "stack" | "vdb" | "checkpoint" | "compact checkpoint"
  // In order: a row ("key", "value") or, with an empty key, a line of its own.
  struct Line {
    std::string key, text;
  };
  std::vector<Line> lines;
  // As `hisnegs info` prints it: rows as "%-12s %s", one line each.
  [[nodiscard]] std::string text() const;
};

// Reads `path` (a stack with `volume`'s channel, dataset, spacing and normalization)
// and describes it; io::InputError for a file of no known kind. With `stack` (a
// checkpoint's own stack, read with `volume`'s options), a checkpoint's row
// "halos" counts its Gaussians brighter than the stack at their centre
// (gmf/core/halo.hpp); `stack` with another kind of file is an InputError.
FileInfo describe_file(const std::filesystem::path& path, const io::VolumeOptions& volume,
                       const std::filesystem::path& stack = {});

}  // namespace hisnegs::apps
