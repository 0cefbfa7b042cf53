// SPDX-License-Identifier: Apache-2.0
// The volume stage: a TIFF stack loaded, normalized and aspect-corrected into a
// sparse OpenVDB grid (config sections volume, sparse_grid), standalone and in a run folder.
#pragma once

#include <filesystem>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "io/sparse_grid.hpp"

namespace hisnegs::apps {

using VolumeConfig = ConfigSlice<&AppConfig::volume, &AppConfig::sparse_grid>;

// Loads + normalizes `volume_path` (or, when it does not fit under reading.max_memory,
// reads it tile by tile: the same grid), builds the sparse grid and writes it to `out`;
// one "vdb: wrote ..." line. Throws io::InputError on a bad stack or setting.
io::SparseGrid write_sparse_grid(const std::filesystem::path& volume_path, const VolumeConfig& config,
                                 const std::filesystem::path& out, const Progress& progress,
                                 const StackReading& reading = {});

// In a run folder: DIR/volume.vdb and DIR/volume.json (source, shape, spacing, aspect,
// normalization, active voxels, file size). Its input is the volume file itself.
struct VolumeStage {
  using Config = VolumeConfig;
  static constexpr const char* kName = "volume";
  static constexpr const char* kTitle = "volume: normalize, aspect-correct, sparse grid";
  static constexpr std::array<const char*, 0> kUpstream{};
  static constexpr std::array<const char*, 2> kOutputs{"volume.vdb", "volume.json"};
  static constexpr const char* kResumeMarker = "";
  static std::string request_inputs(const RunRequest& request);  // the volume file's identity
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
