// SPDX-License-Identifier: Apache-2.0
// ConfigSlice holds copies of exactly its sections, names them in file order,
// writes them as the same YAML dump_app_config does, and cannot reach others.
#include "apps/pipeline/config_slice.hpp"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace hisnegs::apps {
namespace {

using VolumeGmf = ConfigSlice<&AppConfig::gmf, &AppConfig::volume>;  // deliberately not in file order

// Whether `get<Member>()` compiles on a Slice: reading an undeclared section must not.
template <class Slice, auto Member>
concept CanGet = requires(const Slice& slice) {
  slice.template get<Member>();
};

static_assert(CanGet<VolumeGmf, &AppConfig::gmf>);
static_assert(CanGet<VolumeGmf, &AppConfig::volume>);
static_assert(!CanGet<VolumeGmf, &AppConfig::train>);
static_assert(!CanGet<VolumeGmf, &AppConfig::sparse_grid>);
static_assert(VolumeGmf::kHolds<&AppConfig::gmf> && !VolumeGmf::kHolds<&AppConfig::splat>);

TEST(ConfigSlice, HoldsCopiesOfItsSections) {
  AppConfig config;
  config.gmf.gaussians = 1234;
  config.volume.channel = 2;
  const VolumeGmf slice(config);
  config.gmf.gaussians = 1;  // the slice keeps what it was given
  EXPECT_EQ(slice.get<&AppConfig::gmf>().gaussians, 1234);
  EXPECT_EQ(slice.get<&AppConfig::volume>().channel, 2);
}

TEST(ConfigSlice, NamesItsSectionsInFileOrder) {
  EXPECT_EQ(VolumeGmf::section_names(), (std::vector<std::string>{"volume", "gmf"}));
  EXPECT_EQ(ConfigSlice<&AppConfig::splat>::section_names(), std::vector<std::string>{"splat"});
}

TEST(ConfigSlice, TextIsTheDumpOfItsSectionsAlone) {
  AppConfig config;
  config.gmf.gaussians = 777;
  const std::string text = VolumeGmf(config).text();
  // The same lines dump_app_config writes for these sections, without the others.
  const std::string dump = dump_app_config(config);
  const std::string volume = dump.substr(dump.find("volume:"), dump.find("\n\n") - dump.find("volume:") + 1);
  const std::string gmf = dump.substr(dump.find("gmf:"));
  EXPECT_EQ(text, volume + gmf);
  EXPECT_NE(text.find("gaussians: 777"), std::string::npos) << text;
  EXPECT_EQ(text.find("train:"), std::string::npos) << text;
}

TEST(ConfigSlice, SubSliceKeepsTheValues) {
  AppConfig config;
  config.volume.channel = 3;
  const ConfigSlice<& AppConfig::volume> sub = VolumeGmf(config).slice<&AppConfig::volume>();
  EXPECT_EQ(sub.get<&AppConfig::volume>().channel, 3);
  EXPECT_EQ(sub.text(), ConfigSlice<&AppConfig::volume>(config).text());
}

}  // namespace
}  // namespace hisnegs::apps
