// SPDX-License-Identifier: Apache-2.0
// The ground-truth stage: ray-marched MIPs of camera sets (config sections volume,
// raymarch; camera for the run's orbits) as cameras.json, mips.tif, previews/, meta.json.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "io/load_volume.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/ground_truth.hpp"

namespace hisnegs::apps {

// Writes `stack` as DIR/NAME (float32 TIFF, one page per view) and DIR/previews/NNN.png.
void write_image_stack(const std::filesystem::path& dir, const std::string& name, const splat::MipStack& stack);

using RaymarchConfig = ConfigSlice<&AppConfig::raymarch>;

// Ray-marches `cameras` through `loaded` and writes DIR/{cameras.json, mips.tif,
// previews/NNN.png, meta.json}; `label` names the set in progress (a meter of views,
// then one "gt: LABEL: ..." line). `volume_path` is recorded in meta.json.
void write_ground_truth_set(const std::filesystem::path& dir, const std::string& label, const splat::CameraSet& cameras,
                            const io::LoadedVolume& loaded, const std::string& volume_path,
                            const RaymarchConfig& config, splat::Backend backend, const Progress& progress);

struct GroundTruthSet {
  std::string label;  // "train", "eval", "custom", ...
  splat::CameraSet cameras;
};

using GroundTruthSetsConfig = ConfigSlice<&AppConfig::volume, &AppConfig::raymarch>;

// Loads `volume_path` (one "gt: loaded ..." line) and writes each set with
// write_ground_truth_set into DIR/LABEL, or into DIR itself when there is one set.
// With `core_voxels` > 0 the stack is not loaded: it is read brick by brick (cores of
// that edge) and marched by splat::render_ground_truth_streamed (CPU), the same images;
// its statistics come from reading.statistics_cache when that holds them.
void write_ground_truth_sets(const std::filesystem::path& dir, const std::filesystem::path& volume_path,
                             const std::vector<GroundTruthSet>& sets, const GroundTruthSetsConfig& config,
                             splat::Backend backend, const Progress& progress, int core_voxels = 0,
                             const StackReading& reading = {});

// The brick core for `gt` of a stack of `shape` (x, y, z) under reading.max_memory
// (auto = half the RAM): 0 when the whole stack fits (about 112 MiB + 8 bytes per
// voxel), reading.brick_voxels when set, else the largest multiple of 16 whose brick
// fits (reading_core). Throws io::InputError when not even a 16-voxel brick fits or
// the size does not parse.
[[nodiscard]] int ground_truth_core(const std::array<int, 3>& shape, const StackReading& reading,
                                    const Progress& progress);

// The ground-truth set a command reads from a `hisnegs gt` folder DATA: DATA/SET
// when it holds cameras.json (`gt --orbit both`, a run's gt/), else DATA itself when
// it does (one set: `gt --orbit train|eval|custom` or `--cameras`). Throws
// io::InputError naming both places when neither holds one.
[[nodiscard]] std::filesystem::path ground_truth_set_dir(const std::filesystem::path& data, const std::string& set);

// The label `gt` recorded for the set in DIR (meta.json "set": "train", "eval",
// "custom", "cameras"); "" when it recorded none (written by an older hisnegs).
[[nodiscard]] std::string ground_truth_set_label(const std::filesystem::path& dir);

// In a run folder: the training orbit in DIR/gt/train and the evaluation orbit in
// DIR/gt/eval, from the volume file with the volume stage's settings.
struct GroundTruthStage {
  using Config = ConfigSlice<&AppConfig::volume, &AppConfig::camera, &AppConfig::raymarch>;
  static constexpr const char* kName = "ground_truth";
  static constexpr const char* kTitle =
      "ground truth: ray-marched MIPs of the training views (the orbit and camera.close_radii) and the evaluation orbit";
  static constexpr std::array<const char*, 1> kUpstream{"volume"};  // the volume file's identity
  static constexpr std::array<const char*, 2> kOutputs{"gt/train/mips.tif", "gt/eval/mips.tif"};
  static constexpr const char* kResumeMarker = "";
  static std::string request_inputs(const RunRequest&) { return {}; }
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
