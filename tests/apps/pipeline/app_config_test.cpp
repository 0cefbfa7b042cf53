// SPDX-License-Identifier: Apache-2.0
// Every shipped config loads and validates; configs/default.yaml holds every
// field with exactly the in-class defaults; config errors name file and key.
#include "apps/pipeline/app_config.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "apps/pipeline/demo.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {
namespace fs = std::filesystem;

const fs::path kConfigs = testing::source_dir() / "configs";

// Visitor that lists the keys a section's options declare.
struct KeyLister {
  std::vector<std::string> keys;
  template <class T>
  void operator()(std::string_view key, T&) {
    keys.emplace_back(key);
  }
  template <class T, class N>
  void operator()(std::string_view key, T&, N) {
    keys.emplace_back(key);
  }
};

TEST(AppConfig, EveryShippedConfigLoads) {
  int n = 0;
  for (const auto& e : fs::recursive_directory_iterator(kConfigs)) {
    if (e.path().extension() != ".yaml") continue;
    SCOPED_TRACE(e.path().string());
    EXPECT_NO_THROW((void)load_app_config(e.path()));
    ++n;
  }
  EXPECT_GE(n, 1);
}

TEST(AppConfig, DefaultYamlEqualsBuiltInDefaults) {
  const AppConfig from_file = load_app_config(kConfigs / "default.yaml");
  EXPECT_EQ(dump_app_config(from_file), dump_app_config(AppConfig{}));
}

TEST(AppConfig, DemoYamlIsTheBuiltInDemoProfile) {
  std::ifstream in(kConfigs / "demo.yaml");
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  EXPECT_EQ(text, kDemoProfile);
  const AppConfig demo = load_app_config_text(kDemoProfile, "demo profile");
  EXPECT_EQ(dump_app_config(demo), dump_app_config(load_app_config(kConfigs / "demo.yaml")));
  EXPECT_NE(dump_app_config(demo), dump_app_config(AppConfig{}));
}

TEST(AppConfig, DefaultYamlSpellsOutEveryField) {
  // A field missing from default.yaml would still load (defaults are kept), so
  // check the text: each section's keys appear under it.
  std::ifstream in(kConfigs / "default.yaml");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  AppConfig config;
  config.for_each_section([&](const char* section, auto& options) {
    const auto start = text.find("\n" + std::string(section) + ":\n");
    ASSERT_TRUE(start != std::string::npos || text.rfind(std::string(section) + ":\n", 0) == 0) << section;
    const auto from = start == std::string::npos ? 0 : start + 1;
    const auto end = text.find("\n\n", from);
    const std::string body = text.substr(from, end == std::string::npos ? std::string::npos : end - from);
    KeyLister keys;
    options.visit(keys);
    for (const auto& k : keys.keys) {
      EXPECT_NE(body.find("\n  " + k + ":"), std::string::npos) << section << "." << k << " missing";
    }
  });
}

TEST(AppConfig, ErrorsNameFileSectionAndKey) {
  testing::ScratchDir dir;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"camera:\n  widht: 3\n", "unknown key 'camera.widht'"},
      {"camera:\n  width: abc\n", "camera.width: expected an integer"},
      {"camera:\n  width: 4\n", "camera.width = 4"},
      {"train:\n  lr_final: 1.0\n", "train.lr_final"},
      {"splat:\n  mode: fuzzy\n", "expected one of soft|hard"},
      {"cameras: {}\n", "unknown section 'cameras'"},
  };
  for (const auto& [yaml, expect] : cases) {
    testing::write_text(dir / "c.yaml", yaml);
    try {
      (void)load_app_config(dir / "c.yaml");
      ADD_FAILURE() << "no error for " << yaml;
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("c.yaml"), std::string::npos) << e.what();
    }
  }
}

// configs/train_cpu.yaml's train section is the schedule a CPU run picks by itself.
TEST(AppConfig, TrainCpuYamlHoldsTheCpuSchedule) {
  const AppConfig cpu = load_app_config(kConfigs / "train_cpu.yaml");
  AppConfig expected = cpu;
  expected.train = cpu_train_schedule();
  EXPECT_EQ(dump_app_config(cpu), dump_app_config(expected));
}

// The built-in schedule becomes the CPU schedule on the CPU back end only; a config
// that sets any train field keeps its own; the choice is said in one line.
TEST(AppConfig, TheCpuBackEndTrainsWithTheCpuScheduleUnlessOneIsConfigured) {
  std::vector<std::string> lines;
  Progress progress;
  progress.line = [&](std::string_view l) { lines.emplace_back(l); };
  AppConfig config;
  choose_train_schedule(config, splat::Backend::kCpu, progress);
  EXPECT_EQ(config.train.epochs, cpu_train_schedule().epochs);
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_NE(lines[0].find("CPU schedule"), std::string::npos) << lines[0];

  AppConfig gpu;
  choose_train_schedule(gpu, splat::Backend::kCuda, progress);
  EXPECT_EQ(gpu.train.epochs, splat::TrainOptions{}.epochs);

  AppConfig own;
  own.train.lambda_ssim = 0.3;
  choose_train_schedule(own, splat::Backend::kCpu, progress);
  EXPECT_EQ(own.train.epochs, splat::TrainOptions{}.epochs);
  EXPECT_EQ(own.train.lambda_ssim, 0.3);
  EXPECT_EQ(lines.size(), 3u);
}

}  // namespace
}  // namespace hisnegs::apps
