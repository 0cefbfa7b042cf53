// SPDX-License-Identifier: Apache-2.0
// Every stage of the pipeline fingerprints exactly what it reads: a change to any
// field of a section it declares changes its fingerprint, a change anywhere else
// does not; so do its upstream stages' generations and its request inputs.
#include "apps/pipeline/run_stage.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "apps/pipeline/run_pipeline.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;

// Visitor that changes field number `target` of a section (0-based, visit order)
// and counts the fields it passes.
struct FieldChanger {
  int target = -1;
  int seen = 0;
  bool changed = false;
  template <class T>
  void operator()(std::string_view, T& value) {
    if (seen++ == target) changed = change(value);
  }
  template <class E, class Names>
  void operator()(std::string_view, E& value, Names names) {
    if (seen++ != target) return;
    for (const auto& [name, e] : names) {
      if (e != value) {
        value = e;
        changed = true;
        return;
      }
    }
  }
  static bool change(double& v) { return (v = v + 1 + std::abs(v)), true; }
  static bool change(int& v) { return ++v, true; }
  static bool change(std::int64_t& v) { return ++v, true; }
  static bool change(std::uint64_t& v) { return ++v, true; }
  static bool change(bool& v) { return (v = !v), true; }
  static bool change(std::string& v) { return v += "x", true; }
  static bool change(std::array<double, 3>& v) { return v[0] += 1, true; }
  static bool change(std::vector<double>& v) { return v.push_back(1.0), true; }
  static bool change(std::optional<double>& v) { return (v = v ? std::optional<double>{} : 0.5), true; }
};

struct FieldChange {
  std::string section;
  int field = 0;
};

// One change per field of every section of AppConfig.
std::vector<FieldChange> every_field() {
  std::vector<FieldChange> changes;
  AppConfig config;
  config.for_each_section([&](const char* name, auto& options) {
    FieldChanger counter;
    options.visit(counter);
    for (int f = 0; f < counter.seen; ++f) changes.push_back({name, f});
  });
  return changes;
}

AppConfig changed(const FieldChange& change) {
  AppConfig config;
  config.for_each_section([&](const char* name, auto& options) {
    if (name != change.section) return;
    FieldChanger changer{change.field};
    options.visit(changer);
    if (!changer.changed) ADD_FAILURE() << change.section << " field " << change.field << " could not be changed";
  });
  return config;
}

template <class List>
struct AsTestTypes;
template <class... Stages>
struct AsTestTypes<StageList<Stages...>> {
  using type = ::testing::Types<Stages...>;
};

template <class Stage>
class StageFingerprint : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::write_text(dir_ / "volume.tif", "stands in for a stack: only its identity is read");
    request_.volume = dir_ / "volume.tif";
    request_.dir = dir_ / "run";
  }
  std::string fingerprint(const AppConfig& config) const {
    const RunState state(request_.dir);
    return stage_fingerprint<Stage>(typename Stage::Config(config), request_, state);
  }
  testing::ScratchDir dir_;
  RunRequest request_;
};
TYPED_TEST_SUITE(StageFingerprint, AsTestTypes<PipelineStages>::type);

TYPED_TEST(StageFingerprint, FollowsEveryFieldOfTheDeclaredSectionsAndNothingElse) {
  const std::vector<std::string> declared = TypeParam::Config::section_names();
  ASSERT_FALSE(declared.empty());
  const std::string base = this->fingerprint(AppConfig{});
  EXPECT_EQ(this->fingerprint(AppConfig{}), base);  // deterministic
  int declared_fields = 0;
  for (const FieldChange& change : every_field()) {
    const bool is_declared = std::find(declared.begin(), declared.end(), change.section) != declared.end();
    declared_fields += is_declared;
    EXPECT_EQ(this->fingerprint(changed(change)) != base, is_declared)
        << TypeParam::kName << ": " << change.section << " field " << change.field;
  }
  EXPECT_GT(declared_fields, 0);
}

TYPED_TEST(StageFingerprint, FollowsItsUpstreamStages) {
  RunState state(this->request_.dir);
  const typename TypeParam::Config config{AppConfig{}};
  std::string latest = stage_fingerprint<TypeParam>(config, this->request_, state);
  for (const char* upstream : TypeParam::kUpstream) {
    state.set(upstream, RunState::Json{{"state", "done"}});  // redone: a new generation
    const std::string after = stage_fingerprint<TypeParam>(config, this->request_, state);
    EXPECT_NE(after, latest) << TypeParam::kName << " after " << upstream;
    latest = after;
  }
  state.set("unrelated", RunState::Json{{"state", "done"}});
  EXPECT_EQ(stage_fingerprint<TypeParam>(config, this->request_, state), latest) << TypeParam::kName;
}

// The declarations themselves, so that a stage reading a new section shows up here.
TEST(StageDeclarations, SectionsUpstreamAndOutputs) {
  const std::map<std::string, std::vector<std::string>> sections{
      {VolumeStage::kName, VolumeStage::Config::section_names()},
      {GroundTruthStage::kName, GroundTruthStage::Config::section_names()},
      {FitStage::kName, FitStage::Config::section_names()},
      {TrainStage::kName, TrainStage::Config::section_names()},
      {EvalStage::kName, EvalStage::Config::section_names()},
      {OrbitStage::kName, OrbitStage::Config::section_names()}};
  using V = std::vector<std::string>;
  EXPECT_EQ(sections.at("volume"), (V{"volume", "sparse_grid"}));
  EXPECT_EQ(sections.at("ground_truth"), (V{"volume", "camera", "raymarch"}));
  // gmf.background_fraction, gmf.gaussians; the background's estimate and its calibration against the ray marcher.
  EXPECT_EQ(sections.at("fit"), (V{"volume", "background", "sparse_grid", "raymarch", "gmf"}));
  // The 3D term samples the volume as the fit does (volume, sparse_grid, gmf).
  EXPECT_EQ(sections.at("train"), (V{"volume", "sparse_grid", "splat", "train", "gmf"}));
  // The volume's options read the stack the halos are counted against.
  EXPECT_EQ(sections.at("eval"), (V{"volume", "splat"}));
  EXPECT_EQ(sections.at("orbit"), (V{"camera", "splat"}));
  EXPECT_EQ(PipelineStages::kCount, 6);
  EXPECT_STREQ(TrainStage::kResumeMarker, "train/checkpoints/latest");
}

TEST(StageRequestInputs, VolumeFileAndOrbitSettings) {
  testing::ScratchDir dir;
  testing::write_text(dir / "volume.tif", "one");
  RunRequest request;
  request.volume = dir / "volume.tif";
  request.dir = dir / "run";
  const RunState state(request.dir);
  const AppConfig config;
  const std::string volume = stage_fingerprint<VolumeStage>(VolumeStage::Config(config), request, state);
  const std::string orbit = stage_fingerprint<OrbitStage>(OrbitStage::Config(config), request, state);
  const std::string fit = stage_fingerprint<FitStage>(FitStage::Config(config), request, state);
  testing::write_text(dir / "volume.tif", "a different stack");
  request.orbit_frames = 12;
  EXPECT_NE(stage_fingerprint<VolumeStage>(VolumeStage::Config(config), request, state), volume);
  EXPECT_NE(stage_fingerprint<OrbitStage>(OrbitStage::Config(config), request, state), orbit);
  // The fit reads the volume file through the volume stage: its generation, not the file.
  EXPECT_EQ(stage_fingerprint<FitStage>(FitStage::Config(config), request, state), fit);
}

}  // namespace
}  // namespace hisnegs::apps
