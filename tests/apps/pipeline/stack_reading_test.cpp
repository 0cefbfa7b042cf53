// SPDX-License-Identifier: Apache-2.0
// Stages reading a stack by bricks (apps/pipeline/stack_reading.hpp): the brick
// plan under a memory limit, the statistics cache of a run folder, and training's
// 3D term built tile by tile with the same samples as from the whole stack.
#include "apps/pipeline/stack_reading.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <tuple>
#include <vector>

#include "apps/pipeline/fit_stage.hpp"
#include "apps/pipeline/synthetic_stack.hpp"
#include "apps/pipeline/training_volume.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {

// A synthetic stack of 40 x 36 x 20 voxels in `dir`.
std::filesystem::path small_stack(const testing::ScratchDir& dir) {
  AppConfig c;
  c.synth.nx = 40;
  c.synth.ny = 36;
  c.synth.nz = 20;
  (void)write_synthetic_stack(dir / "s.tif", SyntheticConfig(c), Progress{});
  return dir / "s.tif";
}

using Sample = std::tuple<float, float, float, float, float>;
std::vector<Sample> sorted_samples(const splat::VolumeSamples& s) {
  std::vector<Sample> out;
  for (std::size_t i = 0; i < s.size(); ++i) out.emplace_back(s.x[i], s.y[i], s.z[i], s.value[i], s.weight[i]);
  std::sort(out.begin(), out.end());
  return out;
}

TEST(StackReading, BricksOnlyWhenTheStackDoesNotFit) {
  const Progress quiet;
  StackReading r;
  r.max_memory = "200MiB";
  const BrickNeed need;  // 112 MiB + 8 bytes per voxel
  EXPECT_EQ(reading_core({64, 64, 64}, r, need, "gt", quiet), 0);
  // 1024³ voxels need 8 GiB: bricks of a multiple of 16 whose region fits
  const int core = reading_core({1024, 1024, 1024}, r, need, "gt", quiet);
  EXPECT_GT(core, 0);
  EXPECT_EQ(core % 16, 0);
  EXPECT_LE(need.base_bytes + need.bytes_per_voxel * std::pow(core + 2.0, 3), 200.0 * 1048576.0);
  r.brick_voxels = 24;  // asked for: bricks even when it fits
  EXPECT_EQ(reading_core({64, 64, 64}, r, need, "gt", quiet), 24);
  r.brick_voxels = 0;
  r.max_memory = "100MiB";  // under the fixed part: not even the smallest brick
  EXPECT_THROW((void)reading_core({1024, 1024, 1024}, r, need, "gt", quiet), io::InputError);
  r.max_memory = "lots";
  EXPECT_THROW((void)reading_core({64, 64, 64}, r, need, "gt", quiet), io::InputError);
  // Background samples kept in a grid cost a leaf each (up to one per leaf of the
  // stack); handed over as float samples, 40 bytes each.
  io::SparseGridOptions sparse;
  sparse.background_fraction = 0.01;
  const double voxels = 1e9;
  const BrickNeed kept = sparse_grid_need(sparse, voxels, false), taken = sparse_grid_need(sparse, voxels, true);
  EXPECT_NEAR(taken.base_bytes - need.base_bytes, voxels * 0.01 * 40.0, 1.0);
  EXPECT_GT(kept.base_bytes - need.base_bytes, 1e9 / 512.0 * 2048.0);
  sparse.background_fraction = 0;
  EXPECT_EQ(sparse_grid_need(sparse, voxels, false).base_bytes, need.base_bytes);
}

// The statistics pass is cached for the same file and options, redone for others,
// and a damaged cache is a miss, not an error.
TEST(StackReading, TheStatisticsCacheHoldsThePassOfThisFileAndTheseOptions) {
  testing::ScratchDir dir;
  const auto path = small_stack(dir);
  const auto source = io::open_volume_source(path);
  StackReading r;
  r.statistics_cache = dir / "stats.json";
  io::VolumeOptions o;
  const io::Normalization first = source_normalization(*source, o, path, r);
  ASSERT_TRUE(std::filesystem::exists(r.statistics_cache));
  // A cache with another map for this very key is what the next call returns: it was read.
  std::string text = io::read_file(r.statistics_cache);
  const std::string hi = "\"raw_hi\": " + nlohmann::json(first.raw_hi).dump();
  ASSERT_NE(text.find(hi), std::string::npos) << text;
  text.replace(text.find(hi), hi.size(), "\"raw_hi\": 12345.0");
  io::write_file_atomic(r.statistics_cache, text.data(), text.size());
  EXPECT_EQ(source_normalization(*source, o, path, r).raw_hi, 12345.0);
  // Other options: another key, the pass again (and the cache rewritten).
  o.normalization.method = io::NormalizationMethod::kPercentile;
  const io::Normalization percentile = source_normalization(*source, o, path, r);
  EXPECT_NE(percentile.raw_hi, 12345.0);
  EXPECT_EQ(percentile.method, io::NormalizationMethod::kPercentile);
  // Damaged: a miss.
  testing::write_text(r.statistics_cache, "{not json");
  EXPECT_EQ(source_normalization(*source, o, path, r).raw_hi, percentile.raw_hi);
}

// Training's 3D term from a stack read by tiles (the background samples handed over
// tile by tile) is the whole stack's term: the same samples in the same blocks in
// the same order, so the trainer's batches do not depend on the memory limit.
TEST(StackReading, TrainingSamplesOfATiledStackAreTheWholeStacks) {
  testing::ScratchDir dir;
  const auto path = small_stack(dir);
  AppConfig c;
  c.gmf.background_fraction = 0.05;
  const io::LoadedVolume loaded = io::load_volume(path, c.volume);
  const gmf::CheckpointMeta meta = checkpoint_meta(loaded, path.string());
  const auto whole = make_training_volume(path, c.volume, c.sparse_grid, c.gmf, meta, StackReading{}, Progress{});
  StackReading tiles;
  tiles.brick_voxels = 16;
  const auto tiled = make_training_volume(path, c.volume, c.sparse_grid, c.gmf, meta, tiles, Progress{});
  ASSERT_GT(whole->samples().size(), 1000u);
  EXPECT_EQ(whole->blocks(), tiled->blocks());
  EXPECT_TRUE(sorted_samples(whole->samples()) == sorted_samples(tiled->samples())) << "the samples differ";
  const splat::VolumeSamples &a = whole->samples(), &b = tiled->samples();
  EXPECT_EQ(a.block_begin, b.block_begin);
  EXPECT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z && a.value == b.value && a.weight == b.weight)
      << "the same samples in another order";
  tiled->samples().check();
}

}  // namespace
}  // namespace hisnegs::apps
