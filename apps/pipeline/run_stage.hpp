// SPDX-License-Identifier: Apache-2.0
// What every stage of a run folder declares next to its code (the config sections
// it reads, the stages it builds on, the files it writes) and is given (the
// RunRequest), and the fingerprint of its inputs. Reuse rules: run_pipeline.cpp.
#pragma once

#include <array>
#include <concepts>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_state.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "splat/backend.hpp"

namespace hisnegs::apps {

// What `hisnegs run` was asked to do.
struct RunRequest {
  std::filesystem::path volume;  // TIFF stack
  std::filesystem::path dir;     // run folder
  splat::Backend backend = splat::Backend::kCpu;
  bool force = false;     // redo stages finished earlier
  int orbit_frames = 72;  // report Table 10: 72 frames, 5 degree steps
  double orbit_elevation = 30.0;
  // How the stages that read the stack hold it (whole, or by bricks: the same
  // results); not an input of any stage. The fit reads gmf.max_memory.
  StackReading reading{};
};

// A stage of a run folder. Each stage header defines one, e.g.
//   struct FitStage {
//     using Config = ConfigSlice<&AppConfig::volume, &AppConfig::sparse_grid, &AppConfig::gmf>;
//     static constexpr const char* kName = "fit";                 // key in run.json
//     static constexpr const char* kTitle = "GMF fit (stage 1)";  // "run: [i/n] TITLE"
//     static constexpr std::array<const char*, 1> kUpstream{"volume"};  // stages whose results it uses
//     static constexpr std::array<const char*, 2> kOutputs{"gmf.ply", "fit_log.csv"};  // in DIR, all exist when done
//     static constexpr const char* kResumeMarker = "";  // in DIR: lets a started stage resume; "": starts over
//     static std::string request_inputs(const RunRequest&);  // what it reads of the request, as text
//     static nlohmann::ordered_json run(const RunRequest&, const Config&, bool resume, const Progress&);
//   };
// run() gets only its Config slice of the configuration, so it cannot read a section
// its fingerprint does not cover; it returns facts for run.json's top-level key
// kName (null: none). The back end and DIR are not inputs: a stage done on the CPU
// is not redone for CUDA.
template <class S>
concept RunStage = requires(const RunRequest& request, const typename S::Config& config, const Progress& progress,
                            bool resume) {
  { S::kName } -> std::convertible_to<std::string_view>;
  { S::kTitle } -> std::convertible_to<std::string_view>;
  { S::kResumeMarker } -> std::convertible_to<std::string_view>;
  { *S::kUpstream.begin() } -> std::convertible_to<std::string_view>;
  { *S::kOutputs.begin() } -> std::convertible_to<std::string_view>;
  { S::request_inputs(request) } -> std::same_as<std::string>;
  { S::run(request, config, resume, progress) } -> std::same_as<nlohmann::ordered_json>;
};

// The fingerprint of stage S's inputs: the generations of its upstream stages and
// the identities of the outputs they recorded (so files another process wrote
// in between never pass for them), what it reads of the request and the YAML of
// its config slice.
template <RunStage S>
[[nodiscard]] std::string stage_fingerprint(const typename S::Config& config, const RunRequest& request,
                                            const RunState& state) {
  std::string text = std::string(S::kName) + "\n";
  for (const char* upstream : S::kUpstream) {
    text += std::string(upstream) + "@" + std::to_string(state.generation(upstream)) + " " +
            nlohmann::json(state.stage(upstream).value("outputs", nlohmann::ordered_json::object())).dump() +
            "\n";  // nlohmann::json sorts the keys: the text does not depend on their order in run.json
  }
  text += S::request_inputs(request);
  text += config.text();
  return hash_hex(text);
}

}  // namespace hisnegs::apps
