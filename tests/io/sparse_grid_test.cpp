// SPDX-License-Identifier: Apache-2.0
// Tests of io/sparse_grid: the CONVENTIONS transform, threshold + band topology,
// values, the background subsample, bit-exact .vdb round trips, and
// visit_active_leaves over both parts.
#include "io/sparse_grid.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <span>
#include <vector>

#include "io/detail/vdb_grids.hpp"
#include "io/error.hpp"
#include "io/volume_source.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

Volume zeros(int nx, int ny, int nz) {
  Volume v;
  v.nx = nx;
  v.ny = ny;
  v.nz = nz;
  v.voxels.assign(v.size(), 0.0f);
  v.source = "test";
  v.normalization.method = NormalizationMethod::kMinMax;
  return v;
}

Volume random_sparse(int nx, int ny, int nz, double density, std::uint64_t seed) {
  Volume v = zeros(nx, ny, nz);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& x : v.voxels) x = u(rng) < density ? u(rng) : 0.01f * u(rng);
  return v;
}

TEST(SparseGrid, TransformMapsIndexToConventionsWorld) {
  const Volume v = zeros(20, 12, 6);
  const Eigen::Vector3d aspect(1.0, 0.6, 0.3);
  const SparseGrid g = build_sparse_grid(v, aspect, SparseGridOptions{});
  const WorldFrame frame(20, 12, 6, aspect);
  for (const auto& ijk : {openvdb::Coord(0, 0, 0), openvdb::Coord(19, 11, 5), openvdb::Coord(7, 3, 2)}) {
    const openvdb::Vec3d w = g.impl().volume->transform().indexToWorld(ijk);
    const Eigen::Vector3d expect = frame.world_from_index(Eigen::Vector3d(ijk.x(), ijk.y(), ijk.z()));
    EXPECT_NEAR(w.x(), expect.x(), 1e-12);
    EXPECT_NEAR(w.y(), expect.y(), 1e-12);
    EXPECT_NEAR(w.z(), expect.z(), 1e-12);
  }
}

TEST(SparseGrid, OneVoxelDilatesToA26NeighbourhoodCube) {
  Volume v = zeros(16, 16, 16);
  v.at(5, 6, 7) = 0.9f;
  v.at(6, 6, 7) = 0.02f;  // below threshold but inside the band: keeps its value
  SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 1;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  EXPECT_EQ(g.active_voxels(), 27);
  bool active = false;
  EXPECT_FLOAT_EQ(g.value(5, 6, 7, &active), 0.9f);
  EXPECT_TRUE(active);
  EXPECT_FLOAT_EQ(g.value(6, 6, 7, &active), 0.02f);
  EXPECT_TRUE(active);
  (void)g.value(7, 6, 7, &active);
  EXPECT_FALSE(active);
}

TEST(SparseGrid, BandIsClippedToTheStack) {
  Volume v = zeros(10, 10, 10);
  v.at(0, 0, 0) = 1.0f;
  SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 2;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  EXPECT_EQ(g.active_voxels(), 27);  // 3^3: the part of the 5^3 cube inside the stack
  const auto bbox = g.impl().volume->evalActiveVoxelBoundingBox();
  EXPECT_EQ(bbox.min(), openvdb::Coord(0, 0, 0));
  EXPECT_EQ(bbox.max(), openvdb::Coord(2, 2, 2));
}

TEST(SparseGrid, ActiveValuesEqualTheVolumeAndCoverTheForeground) {
  const Volume v = random_sparse(37, 29, 11, 0.02, 3);
  SparseGridOptions o;
  o.threshold = 0.3;
  o.band_voxels = 1;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d(1, 0.8, 0.3), o);
  std::int64_t checked = 0;
  for (auto it = g.impl().volume->cbeginValueOn(); it; ++it) {
    const openvdb::Coord c = it.getCoord();
    ASSERT_EQ(*it, v.at(c.x(), c.y(), c.z()));
    ++checked;
  }
  EXPECT_EQ(checked, g.active_voxels());
  for (int z = 0; z < v.nz; ++z)
    for (int y = 0; y < v.ny; ++y)
      for (int x = 0; x < v.nx; ++x) {
        if (v.at(x, y, z) > 0.3f) {
          bool active = false;
          (void)g.value(x, y, z, &active);
          ASSERT_TRUE(active) << x << " " << y << " " << z;
        }
      }
}

TEST(SparseGrid, BackgroundSubsampleIsSeededDisjointAndOfTheRightSize) {
  const Volume v = random_sparse(64, 64, 16, 0.01, 5);
  SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 1;
  o.background_fraction = 0.05;
  o.seed = 11;
  const SparseGrid a = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  const SparseGrid b = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  EXPECT_EQ(a.background_voxels(), b.background_voxels());
  const double rest = static_cast<double>(v.size() - a.active_voxels());
  const double sd = std::sqrt(rest * 0.05 * 0.95);
  EXPECT_NEAR(static_cast<double>(a.background_voxels()), rest * 0.05, 5 * sd);
  auto fg = a.impl().volume->getConstAccessor();
  auto bg_b = b.impl().background->getConstAccessor();
  for (auto it = a.impl().background->cbeginValueOn(); it; ++it) {
    ASSERT_FALSE(fg.isValueOn(it.getCoord()));
    ASSERT_TRUE(bg_b.isValueOn(it.getCoord()));  // same seed, same samples
    ASSERT_EQ(*it, v.at(it.getCoord().x(), it.getCoord().y(), it.getCoord().z()));
  }
  o.seed = 12;
  const SparseGrid c = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  std::int64_t same = 0;
  auto bg_c = c.impl().background->getConstAccessor();
  for (auto it = a.impl().background->cbeginValueOn(); it; ++it) same += bg_c.isValueOn(it.getCoord());
  EXPECT_LT(same, a.background_voxels() / 2);  // another seed draws other voxels
}

// Every active voxel of `a` is active in `b` with the same value, and the counts agree.
void expect_same_part(const openvdb::FloatGrid& a, const openvdb::FloatGrid& b) {
  ASSERT_EQ(a.activeVoxelCount(), b.activeVoxelCount());
  auto acc = b.getConstAccessor();
  for (auto it = a.cbeginValueOn(); it; ++it) {
    float value = 0;
    ASSERT_TRUE(acc.probeValue(it.getCoord(), value)) << it.getCoord();
    ASSERT_EQ(value, *it) << it.getCoord();
  }
}

// A stack read by tiles (the band and the background samples crossing tile faces,
// tiles that do not divide the stack, non-cubic voxels of raw values, bands wider
// than a tile and than the stack) gives the whole stack's grids voxel for voxel.
TEST(SparseGrid, TilesOfASourceGiveTheWholeStacksGrids) {
  Volume raw = random_sparse(45, 37, 29, 0.004, 9);
  for (float& x : raw.voxels) x = 100.0f + 900.0f * x;  // raw values: normalized by the map below
  Volume normalized = raw;
  normalize(normalized, NormalizationOptions{});
  const Normalization map = normalized.normalization;
  const auto source = memory_source(raw);
  const Eigen::Vector3d aspect(1.0, 37.0 / 45.0, 0.5);
  for (const int band : {0, 1, 3, 9}) {
    SparseGridOptions o;
    o.threshold = 0.4;
    o.band_voxels = band;
    o.background_fraction = 0.03;
    o.seed = 4;
    normalized.source = source->source;
    const SparseGrid whole = build_sparse_grid(normalized, aspect, o);
    for (const int tile : band > 3 ? std::vector<int>{8} : std::vector<int>{8, 16, 24}) {
      int tiles_seen = 0, tiles_total = 0;
      const SparseGrid tiled = build_sparse_grid(*source, map, aspect, o, tile, [&](int done, int total) {
        tiles_seen = done;
        tiles_total = total;
      });
      SCOPED_TRACE("band " + std::to_string(band) + ", tile " + std::to_string(tile));
      EXPECT_GT(whole.active_voxels(), 0);
      if (band <= 3) {  // a wider band covers the whole stack: no background left
        EXPECT_GT(whole.background_voxels(), 0);
      }
      expect_same_part(*whole.impl().volume, *tiled.impl().volume);
      expect_same_part(*whole.impl().background, *tiled.impl().background);
      EXPECT_EQ(tiles_seen, tiles_total);
      EXPECT_EQ(tiled.meta().shape_xyz, whole.meta().shape_xyz);
      EXPECT_EQ(tiled.meta().normalization.raw_hi, map.raw_hi);
      // The background handed over tile by tile instead: the same voxels, none kept.
      std::map<std::array<int, 3>, float> taken;
      const SparseGrid without = build_sparse_grid(
          *source, map, aspect, o, tile, {}, [&](const std::array<int, 3>&, std::span<const ActiveVoxel> voxels) {
            for (const ActiveVoxel& v : voxels) EXPECT_TRUE(taken.emplace(v.index, v.value).second);
          });
      EXPECT_EQ(without.background_voxels(), 0);
      expect_same_part(*whole.impl().volume, *without.impl().volume);
      ASSERT_EQ(static_cast<std::int64_t>(taken.size()), whole.background_voxels());
      auto bg = whole.impl().background->getConstAccessor();
      for (const auto& [index, value] : taken) {
        float expected = 0;
        ASSERT_TRUE(bg.probeValue(openvdb::Coord(index[0], index[1], index[2]), expected));
        ASSERT_EQ(value, expected);
      }
    }
  }
  EXPECT_THROW((void)build_sparse_grid(*source, map, aspect, SparseGridOptions{}, 12), std::invalid_argument);
}

TEST(SparseGrid, VdbRoundTripIsBitExact) {
  testing::ScratchDir dir;
  Volume v = random_sparse(40, 30, 12, 0.03, 7);
  v.spacing.um = {0.3296, 0.3296, 0.9988};
  v.normalization = Normalization{NormalizationMethod::kPercentile, 3.0, 1870.0, 0};
  v.source = "some/stack.tif";
  SparseGridOptions o;
  o.threshold = 0.2;
  o.background_fraction = 0.01;
  o.seed = 4;
  const Eigen::Vector3d aspect(1.0, 0.75, 0.2);
  const SparseGrid g = build_sparse_grid(v, aspect, o);
  write_vdb(dir / "g.vdb", g);
  EXPECT_EQ(dir.entries().size(), 1u);  // no temp file left
  const SparseGrid r = read_vdb(dir / "g.vdb");
  EXPECT_EQ(r.active_voxels(), g.active_voxels());
  EXPECT_EQ(r.background_voxels(), g.background_voxels());
  auto acc = r.impl().volume->getConstAccessor();
  for (auto it = g.impl().volume->cbeginValueOn(); it; ++it) {
    ASSERT_TRUE(acc.isValueOn(it.getCoord()));
    ASSERT_EQ(acc.getValue(it.getCoord()), *it);
  }
  const SparseGridMeta& m = r.meta();
  EXPECT_EQ(m.shape_xyz, (std::array<int, 3>{40, 30, 12}));
  EXPECT_EQ(m.spacing_um, v.spacing.um);
  EXPECT_EQ(m.aspect, aspect);
  EXPECT_EQ(m.normalization.method, NormalizationMethod::kPercentile);
  EXPECT_EQ(m.normalization.raw_lo, 3.0);
  EXPECT_EQ(m.normalization.raw_hi, 1870.0);
  EXPECT_EQ(m.source, "some/stack.tif");
  EXPECT_EQ(m.options.threshold, 0.2);
  EXPECT_EQ(m.options.seed, 4u);
  EXPECT_TRUE(r.frame().voxel_size().isApprox(WorldFrame(40, 30, 12, aspect).voxel_size()));
}

TEST(SparseGrid, InspectListsGridsAndMetadata) {
  testing::ScratchDir dir;
  const Volume v = random_sparse(32, 32, 8, 0.01, 9);
  SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 0;
  o.background_fraction = 0.02;
  write_vdb(dir / "g.vdb", build_sparse_grid(v, Eigen::Vector3d::Ones(), o));
  const auto grids = inspect_vdb(dir / "g.vdb");
  ASSERT_EQ(grids.size(), 2u);
  const bool volume_first = grids[0].name == "volume";
  const VdbGridSummary& vol = grids[volume_first ? 0 : 1];
  const VdbGridSummary& bg = grids[volume_first ? 1 : 0];
  EXPECT_EQ(vol.name, "volume");
  EXPECT_EQ(vol.value_type, "float");
  EXPECT_GT(vol.active_voxels, 0);
  ASSERT_EQ(vol.metadata.count("normalization"), 1u);
  EXPECT_EQ(vol.metadata.at("normalization"), "minmax");
  EXPECT_EQ(bg.name, "background");
  EXPECT_GT(bg.active_voxels, 0);
}

TEST(SparseGrid, BadFilesAreOneLineInputErrors) {
  testing::ScratchDir dir;
  testing::write_text(dir / "text.vdb", "this is not a vdb file\n");
  for (const auto& p : {dir / "text.vdb", dir / "missing.vdb", dir.path()}) {
    try {
      (void)read_vdb(p);
      FAIL() << "expected InputError for " << p;
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(p.string()), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    }
  }
}

TEST(SparseGrid, OptionsAreValidated) {
  SparseGridOptions o;
  o.threshold = 1.5;
  EXPECT_THROW(o.validate(), InputError);
  o = SparseGridOptions{};
  o.band_voxels = -1;
  EXPECT_THROW(o.validate(), InputError);
  o = SparseGridOptions{};
  o.background_fraction = 2.0;
  EXPECT_THROW(o.validate(), InputError);
}

// visit_active_leaves over `part` against OpenVDB's own list of active voxels:
// each active voxel exactly once with its value (= the volume's), grouped by
// the 8³ leaf holding it, each leaf once with its origin (a multiple of 8).
void expect_visits_every_active_voxel_once(const SparseGrid& g, SparseGridPart part, const Volume& v) {
  const openvdb::FloatGrid& grid = part == SparseGridPart::kForeground ? *g.impl().volume : *g.impl().background;
  std::map<std::array<int, 3>, float> expected;
  for (auto it = grid.cbeginValueOn(); it; ++it) {
    expected[{it.getCoord().x(), it.getCoord().y(), it.getCoord().z()}] = *it;
  }
  ASSERT_GT(expected.size(), 50u);
  std::set<std::array<int, 3>> leaves, seen;
  g.visit_active_leaves(part, [&](const std::array<int, 3>& origin, std::span<const ActiveVoxel> voxels) {
    EXPECT_TRUE(leaves.insert(origin).second) << "leaf visited twice";
    EXPECT_FALSE(voxels.empty());
    for (int a = 0; a < 3; ++a) EXPECT_EQ(origin[a] % 8, 0);
    for (const ActiveVoxel& av : voxels) {
      for (int a = 0; a < 3; ++a) {
        EXPECT_GE(av.index[a], origin[a]);
        EXPECT_LT(av.index[a], origin[a] + 8);
      }
      EXPECT_TRUE(seen.insert(av.index).second) << "voxel visited twice";
      const auto it = expected.find(av.index);
      ASSERT_NE(it, expected.end()) << "visited an inactive voxel";
      EXPECT_EQ(av.value, it->second);
      EXPECT_EQ(av.value, v.at(av.index[0], av.index[1], av.index[2]));
    }
  });
  EXPECT_EQ(seen.size(), expected.size());
  EXPECT_EQ(static_cast<std::int64_t>(seen.size()),
            part == SparseGridPart::kForeground ? g.active_voxels() : g.background_voxels());
  // The leaves visited are exactly those holding active voxels.
  std::set<std::array<int, 3>> holding;
  for (const auto& [idx, value] : expected) holding.insert({idx[0] & ~7, idx[1] & ~7, idx[2] & ~7});
  EXPECT_EQ(leaves, holding);
}

TEST(SparseGrid, VisitActiveLeavesVisitsEveryForegroundVoxelOnce) {
  const Volume v = random_sparse(37, 29, 11, 0.02, 13);
  SparseGridOptions o;
  o.threshold = 0.3;
  o.band_voxels = 1;
  o.background_fraction = 0.05;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d(1, 0.8, 0.3), o);
  expect_visits_every_active_voxel_once(g, SparseGridPart::kForeground, v);
}

TEST(SparseGrid, VisitActiveLeavesVisitsEveryBackgroundVoxelOnce) {
  const Volume v = random_sparse(37, 29, 11, 0.02, 17);
  SparseGridOptions o;
  o.threshold = 0.3;
  o.band_voxels = 1;
  o.background_fraction = 0.05;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d(1, 0.8, 0.3), o);
  expect_visits_every_active_voxel_once(g, SparseGridPart::kBackground, v);
}

// Without background samples the background part has no leaf to visit.
TEST(SparseGrid, VisitActiveLeavesOfAnEmptyBackgroundVisitsNothing) {
  const Volume v = random_sparse(20, 20, 9, 0.02, 19);
  SparseGridOptions o;
  o.threshold = 0.3;
  const SparseGrid g = build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  int visits = 0;
  g.visit_active_leaves(SparseGridPart::kBackground, [&](const auto&, auto) { ++visits; });
  EXPECT_EQ(visits, 0);
}

// A leaf whose voxels were all switched off (OpenVDB keeps it) is not visited.
TEST(SparseGrid, VisitActiveLeavesSkipsLeavesWithoutActiveVoxels) {
  auto impl = std::make_shared<SparseGrid::Impl>(SparseGrid().impl());  // initializes OpenVDB
  impl->volume = openvdb::FloatGrid::create(0.0f);
  auto acc = impl->volume->getAccessor();
  acc.setValueOn(openvdb::Coord(3, 3, 3), 0.5f);
  acc.setValueOn(openvdb::Coord(20, 1, 1), 0.25f);
  acc.setValueOff(openvdb::Coord(20, 1, 1));
  ASSERT_EQ(impl->volume->tree().leafCount(), 2u);
  const SparseGrid g(impl);
  std::vector<std::array<int, 3>> origins;
  g.visit_active_leaves(SparseGridPart::kForeground, [&](const std::array<int, 3>& origin, auto voxels) {
    origins.push_back(origin);
    ASSERT_EQ(voxels.size(), 1u);
    EXPECT_EQ(voxels[0].index, (std::array<int, 3>{3, 3, 3}));
    EXPECT_EQ(voxels[0].value, 0.5f);
  });
  EXPECT_EQ(origins, (std::vector<std::array<int, 3>>{{0, 0, 0}}));
}

}  // namespace
}  // namespace hisnegs::io
