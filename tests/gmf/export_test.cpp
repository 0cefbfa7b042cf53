// SPDX-License-Identifier: Apache-2.0
// Tests of gmf/export_vdb (density values and topology against direct evaluation of
// f, transforms, metadata, thread independence, points round trip, rejected input)
// and gmf/export_formats (splat-viewer PLY mapping, dense resampling). Written files
// are read back with OpenVDB's own API; every fixture is generated here.
#include "gmf/export_vdb.hpp"

#include <gtest/gtest.h>
#include <openvdb/io/File.h>
#include <openvdb/points/PointCount.h>
#include <openvdb/points/PointDataGrid.h>
#include <tbb/global_control.h>
#include <Eigen/LU>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <optional>
#include <random>

#include "gmf/core/export_formats.hpp"
#include "io/error.hpp"
#include "io/sparse_grid.hpp"
#include "io/vdb_file.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

// Gaussians inside the box [-0.8, 0.8]² × [-0.4, 0.4] of a 40 × 40 × 20 stack with
// aspect (1, 1, 0.5): σ 1-4 voxels, random (non-unit) rotations, a in (0.05, 0.95).
GaussianMixture random_mixture(std::size_t k, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> xy(-0.8f, 0.8f), z(-0.4f, 0.4f), log_scale(std::log(0.05f), std::log(0.2f)),
      logit(-3.0f, 3.0f);
  std::normal_distribution<float> quat(0.0f, 1.0f);
  GaussianMixture m;
  for (std::size_t i = 0; i < k; ++i) {
    GaussianParams g;
    g.mean = {xy(rng), xy(rng), z(rng)};
    for (float& v : g.log_scale) v = log_scale(rng);
    for (float& v : g.rotation) v = quat(rng);
    g.intensity_logit = logit(rng);
    m.push_back(g);
  }
  return m;
}

CheckpointMeta stack_meta() {
  CheckpointMeta meta;
  meta.volume_shape_zyx = std::array<int, 3>{20, 40, 40};
  meta.spacing_um = std::array<double, 3>{0.5, 0.5, 1.0};
  meta.aspect = std::array<double, 3>{1.0, 1.0, 0.5};
  meta.normalization = "minmax 0 254";
  meta.extra = {{"source", "stack.tif"}, {"note", "two  spaces kept"}};
  return meta;
}

const io::WorldFrame kFrame(40, 40, 20, Eigen::Vector3d(1.0, 1.0, 0.5));

openvdb::GridBase::Ptr read_grid(const fs::path& path, const std::string& name) {
  io::ensure_openvdb_initialized();
  openvdb::io::File file(path.string());
  file.open(false);
  openvdb::GridBase::Ptr grid = file.readGrid(name);
  file.close();
  return grid;
}

openvdb::FloatGrid::Ptr read_density(const fs::path& path) {
  return openvdb::gridPtrCast<openvdb::FloatGrid>(read_grid(path, "density"));
}

Eigen::Vector3d world_of(const openvdb::FloatGrid& grid, const openvdb::Coord& c) {
  const openvdb::Vec3d w = grid.transform().indexToWorld(c);
  return {w.x(), w.y(), w.z()};
}

// The mixture's f, brute force in double: at world point x the terms
// g_k = a_k exp(-m_k/2) with m_k <= support, weighted by softmax(β g) (report Eq. 8
// in 3D; operator()) or summed (Eq. 1 inside the support; sum()); 0 where none.
class SoftmaxReference {
 public:
  SoftmaxReference(const GaussianMixture& mixture, double beta, double support) : beta_(beta), support_(support) {
    for (const GaussianParams& p : mixture) {
      terms_.push_back(
          {Eigen::Vector3d(p.mean[0], p.mean[1], p.mean[2]), covariance(p).inverse(), intensity<double>(p)});
    }
  }
  double sum(const Eigen::Vector3d& x) const {
    double f = 0;
    for (const Term& t : terms_) {
      const Eigen::Vector3d d = x - t.mean;
      const double m = d.dot(t.precision * d);
      if (m <= support_) f += t.a * std::exp(-0.5 * m);
    }
    return f;
  }
  double operator()(const Eigen::Vector3d& x) const {
    std::vector<double> g;
    double top = -1, num = 0, den = 0;
    for (const Term& t : terms_) {
      const Eigen::Vector3d d = x - t.mean;
      const double m = d.dot(t.precision * d);
      if (m > support_) continue;
      g.push_back(t.a * std::exp(-0.5 * m));
      top = std::max(top, g.back());
    }
    for (double v : g) {
      const double w = std::exp(beta_ * (v - top));
      num += w * v;
      den += w;
    }
    return den > 0 ? num / den : 0.0;
  }

 private:
  struct Term {
    Eigen::Vector3d mean;
    Eigen::Matrix3d precision;
    double a;
  };
  std::vector<Term> terms_;
  double beta_, support_;
};

// A checkpoint of dense, overlapping Gaussians recorded as a softmax at β 64.
Checkpoint softmax_checkpoint() {
  Checkpoint cp{random_mixture(60, 21), stack_meta()};
  cp.meta.aggregation = Aggregation::kSoftmax;
  cp.meta.beta = 64.0;
  return cp;
}

// Over every voxel of kFrame, exported values `value(x, y, z)` against the
// checkpoint's f_β: the largest |value − f_β| where f_β > floor, and the largest
// (Σ terms − value), how far below the sum of the terms they sit.
struct SoftmaxGaps {
  double max_diff = 0, max_sum_gap = 0;
};
template <class Value>
SoftmaxGaps gaps_to_softmax(const GaussianMixture& mixture, double floor, Value&& value) {
  const SoftmaxReference reference(mixture, 64.0, 16.0);
  SoftmaxGaps gaps;
  for (int z = 0; z < 20; ++z)
    for (int y = 0; y < 40; ++y)
      for (int x = 0; x < 40; ++x) {
        const Eigen::Vector3d w = kFrame.world_from_index(Eigen::Vector3d(x, y, z));
        const double v = value(x, y, z), f = reference(w);
        if (f > floor) gaps.max_diff = std::max(gaps.max_diff, std::abs(v - f));
        gaps.max_sum_gap = std::max(gaps.max_sum_gap, evaluate_mixture(mixture, w) - v);
      }
  return gaps;
}

bool bit_equal(const GaussianMixture& a, const GaussianMixture& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(GaussianParams)) == 0);
}

TEST(ExportVdb, DensityMatchesDirectEvaluationAndInactiveVoxelsStayBelowCutoff) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(25, 7), stack_meta()};
  VdbExportOptions options;
  options.cutoff = 1e-3;
  const VdbExportReport report = export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), options, "m.ply");
  const auto grid = read_density(dir / "m.vdb");
  ASSERT_TRUE(grid);
  EXPECT_EQ(static_cast<std::int64_t>(grid->activeVoxelCount()), report.active_voxels);
  ASSERT_GT(report.active_voxels, 1000);
  // Only the stack's voxels can be active.
  const openvdb::CoordBBox stack(openvdb::Coord(0, 0, 0), openvdb::Coord(39, 39, 19));
  EXPECT_TRUE(stack.isInside(grid->evalActiveVoxelBoundingBox()));

  // Every voxel of the stack: active values are the fitted f (each term inside its
  // support δ, as the fit and the renderer count it) within 1e-5 (the stored float
  // and the per-Gaussian truncation at `tail` are both far below that), inactive
  // voxels hold the background 0 and have f <= cutoff (+ the truncation bound, 25 × tail).
  const SoftmaxReference fitted(cp.mixture, 1.0, options.support);
  const auto acc = grid->getConstAccessor();
  std::int64_t active = 0, inactive = 0;
  double max_diff = 0, max_inactive_f = 0;
  for (int z = 0; z < 20; ++z)
    for (int y = 0; y < 40; ++y)
      for (int x = 0; x < 40; ++x) {
        const openvdb::Coord c(x, y, z);
        const double f = fitted.sum(kFrame.world_from_index(Eigen::Vector3d(x, y, z)));
        if (acc.isValueOn(c)) {
          ++active;
          max_diff = std::max(max_diff, std::abs(acc.getValue(c) - f));
          EXPECT_GT(acc.getValue(c), options.cutoff) << x << " " << y << " " << z;
        } else {
          ++inactive;
          max_inactive_f = std::max(max_inactive_f, f);
          ASSERT_EQ(acc.getValue(c), 0.0f);
        }
      }
  EXPECT_EQ(active, report.active_voxels);
  EXPECT_GT(inactive, 10000);
  EXPECT_LT(max_diff, 1e-5);
  EXPECT_LE(max_inactive_f, options.cutoff + 25 * options.tail);
}

// Issue 32, item 15: a sum checkpoint exports the function that was fitted (every
// term inside its support δ), not the untruncated sum (which differed from it by up
// to 2.1e-3 on op1); the untruncated sum is an explicit option, and the metadata
// says which.
TEST(ExportVdb, SumCheckpointExportsTheFittedFUnlessAskedForTheWholeSum) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(60, 21), stack_meta()};  // dense: tails reach other Gaussians' cores
  VdbExportOptions options;
  options.support = 9.0;
  export_vdb(dir / "fitted.vdb", cp, VoxelLattice::of(kFrame), options, "m.ply");
  options.untruncated_sum = true;
  export_vdb(dir / "whole.vdb", cp, VoxelLattice::of(kFrame), options, "m.ply");
  const auto fitted = read_density(dir / "fitted.vdb"), whole = read_density(dir / "whole.vdb");
  ASSERT_TRUE(fitted && whole);
  EXPECT_EQ(fitted->metaValue<double>("support"), 9.0);
  EXPECT_FALSE(fitted->metaValue<bool>("untruncated_sum"));
  EXPECT_TRUE(whole->metaValue<bool>("untruncated_sum"));
  EXPECT_FALSE(whole->getMetadata<openvdb::DoubleMetadata>("support"));
  const SoftmaxReference reference(cp.mixture, 1.0, 9.0);
  const auto a = fitted->getConstAccessor(), b = whole->getConstAccessor();
  double fitted_diff = 0, whole_diff = 0, tails = 0;
  for (int z = 0; z < 20; ++z)
    for (int y = 0; y < 40; ++y)
      for (int x = 0; x < 40; ++x) {
        const openvdb::Coord c(x, y, z);
        const Eigen::Vector3d w = kFrame.world_from_index(Eigen::Vector3d(x, y, z));
        const double f = reference.sum(w), all = evaluate_mixture(cp.mixture, w);
        if (f > 2 * options.cutoff) fitted_diff = std::max(fitted_diff, std::abs(a.getValue(c) - f));
        if (all > 2 * options.cutoff) whole_diff = std::max(whole_diff, std::abs(b.getValue(c) - all));
        tails = std::max(tails, all - f);
      }
  EXPECT_LT(fitted_diff, 1e-5);
  EXPECT_LT(whole_diff, 1e-5);
  EXPECT_GT(tails, 1e-3);  // the two functions do differ here: the test tells them apart
}

// A softmax checkpoint exports its own f_β (support δ), not the sum of its terms:
// the `density` values are the brute-force softmax, and its metadata says which f.
TEST(ExportVdb, SoftmaxCheckpointExportsItsOwnF) {
  ScratchDir dir;
  const Checkpoint cp = softmax_checkpoint();
  VdbExportOptions options;
  options.support = 16.0;
  export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), options, "m.ply");
  const auto grid = read_density(dir / "m.vdb");
  ASSERT_TRUE(grid);
  EXPECT_EQ(grid->metaValue<std::string>("aggregation"), "softmax");
  EXPECT_EQ(grid->metaValue<double>("beta"), 64.0);
  EXPECT_EQ(grid->metaValue<double>("support"), 16.0);
  const auto acc = grid->getConstAccessor();
  const SoftmaxGaps gaps = gaps_to_softmax(cp.mixture, 2 * options.cutoff,
                                           [&](int x, int y, int z) { return acc.getValue(openvdb::Coord(x, y, z)); });
  EXPECT_LT(gaps.max_diff, 1e-5);
  EXPECT_GT(gaps.max_sum_gap, 0.1);  // where terms overlap the sum is far above f_β
  // A sum checkpoint says so and carries no β.
  export_vdb(dir / "sum.vdb", Checkpoint{cp.mixture, stack_meta()}, VoxelLattice::of(kFrame), options, "m.ply");
  const auto sum = read_density(dir / "sum.vdb");
  EXPECT_EQ(sum->metaValue<std::string>("aggregation"), "sum");
  EXPECT_FALSE(sum->getMetadata<openvdb::DoubleMetadata>("beta"));
}

TEST(ExportVdb, StaysInsideTheStackWhereTheFitSawData) {
  ScratchDir dir;
  GaussianMixture m;
  GaussianParams g;  // σ = 0.2 (4 voxels) at the +x face of the box: half of it lies outside
  g.mean = {1.0f, 0.0f, 0.0f};
  g.log_scale = {std::log(0.2f), std::log(0.2f), std::log(0.2f)};
  m.push_back(g);
  export_vdb(dir / "stack.vdb", Checkpoint{m, stack_meta()}, VoxelLattice::of(kFrame), VdbExportOptions{}, "m.ply");
  const openvdb::CoordBBox box = read_density(dir / "stack.vdb")->evalActiveVoxelBoundingBox();
  EXPECT_EQ(box.max().x(), 39);
  EXPECT_EQ(box.min().z(), 0);
  EXPECT_EQ(box.max().z(), 19);

  // An aligned lattice clipped to the same box: centres in [-a, a] only.
  const VoxelLattice aligned = VoxelLattice::aligned(0.1).clipped_to_box(Eigen::Vector3d(1.0, 1.0, 0.5));
  ASSERT_TRUE(aligned.clip.has_value());
  EXPECT_EQ(aligned.clip->min, Eigen::Vector3i(-10, -10, -5));
  EXPECT_EQ(aligned.clip->max, Eigen::Vector3i(10, 10, 5));
  export_vdb(dir / "aligned.vdb", Checkpoint{m, stack_meta()}, aligned, VdbExportOptions{}, "m.ply");
  const auto grid = read_density(dir / "aligned.vdb");
  EXPECT_EQ(grid->evalActiveVoxelBoundingBox().max().x(), 10);
  EXPECT_EQ(grid->metaValue<openvdb::Vec3i>("clip_max"), openvdb::Vec3i(10, 10, 5));
  // Unclipped, the Gaussian's far side is there too.
  export_vdb(dir / "free.vdb", Checkpoint{m, stack_meta()}, VoxelLattice::aligned(0.1), VdbExportOptions{}, "m.ply");
  EXPECT_GT(read_density(dir / "free.vdb")->evalActiveVoxelBoundingBox().max().x(), 15);
}

TEST(ExportVdb, MatchedLatticeUsesTheStackTransform) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(3, 1), stack_meta()};
  export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), VdbExportOptions{}, "m.ply");
  const auto grid = read_density(dir / "m.vdb");
  ASSERT_TRUE(grid);
  // The same map as the `vdb` command's grids, so the voxels coincide with the stack's.
  EXPECT_EQ(grid->transform(),
            *io::make_vdb_transform(kFrame.voxel_size(), kFrame.world_from_index(Eigen::Vector3d::Zero())));
  for (const openvdb::Coord c : {openvdb::Coord(0, 0, 0), openvdb::Coord(39, 39, 19), openvdb::Coord(-3, 5, 21)}) {
    const Eigen::Vector3d expect = kFrame.world_from_index(Eigen::Vector3d(c.x(), c.y(), c.z()));
    EXPECT_LT((world_of(*grid, c) - expect).norm(), 1e-12);
  }
  EXPECT_EQ(grid->getGridClass(), openvdb::GRID_FOG_VOLUME);
}

TEST(ExportVdb, AlignedLatticePutsAVoxelCentreAtTheOrigin) {
  ScratchDir dir;
  GaussianMixture m;
  GaussianParams g;  // isotropic σ = 0.1 at the origin, a = 0.5
  g.log_scale = {std::log(0.1f), std::log(0.1f), std::log(0.1f)};
  m.push_back(g);
  const double v = 0.025;
  export_vdb(dir / "m.vdb", Checkpoint{m, {}}, VoxelLattice::aligned(v), VdbExportOptions{}, "m.ply");
  const auto grid = read_density(dir / "m.vdb");
  ASSERT_TRUE(grid);
  EXPECT_NEAR(grid->voxelSize().x(), v, 1e-15);
  EXPECT_LT(world_of(*grid, openvdb::Coord(0, 0, 0)).norm(), 1e-15);
  EXPECT_FLOAT_EQ(grid->tree().getValue(openvdb::Coord(0, 0, 0)), 0.5f);
  // Symmetric around the origin: f > 1e-3 for r < 0.1 sqrt(2 ln 500) = 0.3526, i.e. 14 voxels.
  const openvdb::CoordBBox box = grid->evalActiveVoxelBoundingBox();
  EXPECT_EQ(box.min(), openvdb::Coord(-14, -14, -14));
  EXPECT_EQ(box.max(), openvdb::Coord(14, 14, 14));
  const Eigen::Vector3d w = world_of(*grid, openvdb::Coord(-7, 3, 11));
  EXPECT_NEAR(grid->tree().getValue(openvdb::Coord(-7, 3, 11)), evaluate_mixture(m, w), 1e-7);
}

TEST(ExportVdb, RecordsTheCheckpointMetadata) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(4, 2), stack_meta()};
  VdbExportOptions options;
  options.cutoff = 2e-3;
  export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), options, "models/m.ply");
  const auto grid = read_density(dir / "m.vdb");
  ASSERT_TRUE(grid);
  EXPECT_EQ(grid->metaValue<openvdb::Int64>("gaussians"), 4);
  EXPECT_EQ(grid->metaValue<double>("cutoff"), 2e-3);
  EXPECT_EQ(grid->metaValue<std::string>("model"), "models/m.ply");
  EXPECT_EQ(grid->metaValue<std::string>("source"), "stack.tif");
  EXPECT_EQ(grid->metaValue<std::string>("normalization"), "minmax 0 254");
  EXPECT_EQ(grid->metaValue<openvdb::Vec3i>("volume_shape_xyz"), openvdb::Vec3i(40, 40, 20));
  EXPECT_EQ(grid->metaValue<openvdb::Vec3d>("spacing_um"), openvdb::Vec3d(0.5, 0.5, 1.0));
  EXPECT_EQ(grid->metaValue<openvdb::Vec3d>("aspect"), openvdb::Vec3d(1.0, 1.0, 0.5));
}

TEST(ExportVdb, ValuesDoNotDependOnTheThreadCount) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(40, 3), stack_meta()};
  export_vdb(dir / "many.vdb", cp, VoxelLattice::of(kFrame), VdbExportOptions{}, "m.ply");
  {
    const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    export_vdb(dir / "one.vdb", cp, VoxelLattice::of(kFrame), VdbExportOptions{}, "m.ply");
  }
  const auto a = read_density(dir / "many.vdb"), b = read_density(dir / "one.vdb");
  ASSERT_EQ(a->activeVoxelCount(), b->activeVoxelCount());
  ASSERT_TRUE(a->tree().hasSameTopology(b->tree()));
  const auto acc = b->getConstAccessor();
  for (auto it = a->cbeginValueOn(); it; ++it) ASSERT_EQ(*it, acc.getValue(it.getCoord())) << it.getCoord();
}

TEST(ExportVdb, ReportsProgressUpToTheCandidateLeaves) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(40, 4), stack_meta()};
  std::int64_t calls = 0, last = 0, total_seen = 0;
  const VdbExportReport r = export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), VdbExportOptions{}, "m.ply",
                                       [&](std::int64_t done, std::int64_t total) {
                                         ++calls;
                                         EXPECT_LE(done, total);
                                         last = std::max(last, done);
                                         total_seen = total;
                                       });
  EXPECT_GE(calls, 10);
  EXPECT_EQ(total_seen, r.candidate_leaves);
  EXPECT_GE(last, r.candidate_leaves * 9 / 10);
  EXPECT_LE(r.leaf_count, r.candidate_leaves);
}

TEST(ExportVdb, PointsRoundTripIsBitIdentical) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(300, 5), stack_meta()};
  VdbExportOptions options;
  options.points = true;
  export_vdb(dir / "m.vdb", cp, VoxelLattice::of(kFrame), options, "m.ply");
  const auto points = openvdb::gridPtrCast<openvdb::points::PointDataGrid>(read_grid(dir / "m.vdb", "gaussians"));
  ASSERT_TRUE(points);
  EXPECT_EQ(openvdb::points::pointCount(points->tree()), 300u);
  const Checkpoint back = import_vdb_points(dir / "m.vdb");
  EXPECT_TRUE(bit_equal(back.mixture, cp.mixture));
  EXPECT_EQ(back.meta, cp.meta);
}

TEST(ExportVdb, EmptyModelExportsAndImports) {
  ScratchDir dir;
  VdbExportOptions options;
  options.points = true;
  const VdbExportReport r = export_vdb(dir / "e.vdb", Checkpoint{}, VoxelLattice::aligned(0.1), options, "e.ply");
  EXPECT_EQ(r.active_voxels, 0);
  const Checkpoint back = import_vdb_points(dir / "e.vdb");
  EXPECT_TRUE(back.mixture.empty());
  EXPECT_EQ(back.meta, CheckpointMeta{});
}

TEST(ExportVdb, ImportRejectsFilesWithoutHisnegsPoints) {
  ScratchDir dir;
  export_vdb(dir / "density_only.vdb", Checkpoint{random_mixture(2, 6), {}}, VoxelLattice::aligned(0.1),
             VdbExportOptions{}, "m.ply");
  const auto expect_error = [](const fs::path& p, const std::string& needle) {
    try {
      (void)import_vdb_points(p);
      ADD_FAILURE() << p << " was accepted";
    } catch (const io::InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(p.string()), std::string::npos) << what;
      EXPECT_NE(what.find(needle), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    }
  };
  expect_error(dir / "density_only.vdb", "no grid named 'gaussians'");
  testing::write_text(dir / "text.vdb", "not a vdb\n");
  expect_error(dir / "text.vdb", "not a .vdb file");
  expect_error(dir / "missing.vdb", "no such file");
}

TEST(ExportVdb, ImportRejectsIdsThatDoNotNumberThePoints) {
  ScratchDir dir;
  VdbExportOptions options;
  options.points = true;
  export_vdb(dir / "m.vdb", Checkpoint{random_mixture(20, 12), stack_meta()}, VoxelLattice::of(kFrame), options,
             "m.ply");
  // Give the first point of the first leaf the id of the second point: one id twice.
  auto points = openvdb::gridPtrCast<openvdb::points::PointDataGrid>(read_grid(dir / "m.vdb", "gaussians"));
  ASSERT_TRUE(points);
  auto leaf = points->tree().beginLeaf();
  ASSERT_TRUE(leaf);
  ASSERT_GE(openvdb::points::pointCount(points->tree()), 2u);
  std::vector<std::int32_t> ids;
  for (auto l = points->tree().cbeginLeaf(); l; ++l) {
    openvdb::points::AttributeHandle<std::int32_t> h(l->constAttributeArray("id"));
    for (auto i = l->beginIndexAll(); i; ++i) ids.push_back(h.get(*i));
  }
  openvdb::points::AttributeWriteHandle<std::int32_t> id(leaf->attributeArray("id"));
  id.set(0, ids[1]);
  io::write_vdb_file(dir / "bad.vdb", openvdb::GridPtrVec{points});
  try {
    (void)import_vdb_points(dir / "bad.vdb");
    ADD_FAILURE() << "duplicate id accepted";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("point attribute 'id' = " + std::to_string(ids[1]) + " is given twice"),
              std::string::npos)
        << e.what();
  }
}

// Point attributes state their own sizes, so import reads only the point grids
// hisnegs wrote: their bytes must match the checksum written with them.
TEST(ExportVdb, ImportReadsOnlyPointGridsMatchingTheirChecksum) {
  ScratchDir dir;
  VdbExportOptions options;
  options.points = true;
  const Checkpoint checkpoint{random_mixture(20, 12), stack_meta()};
  export_vdb(dir / "m.vdb", checkpoint, VoxelLattice::of(kFrame), options, "m.ply");
  EXPECT_EQ(import_vdb_points(dir / "m.vdb").mixture.size(), checkpoint.mixture.size());
  for (const io::VdbGridSummary& g : io::inspect_vdb(dir / "m.vdb")) EXPECT_TRUE(g.values_read) << g.name;
  auto expect_refused = [&](const std::filesystem::path& path, const std::string& needle) {
    try {
      (void)import_vdb_points(path);
      ADD_FAILURE() << "accepted " << path;
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  // The same grid written by OpenVDB itself: no checksum.
  const auto points = read_grid(dir / "m.vdb", "gaussians");
  openvdb::io::File(dir.path().string() + "/plain.vdb").write(openvdb::GridPtrVec{points});
  expect_refused(dir / "plain.vdb", "grid 'gaussians' carries no hisnegs checksum");
  // One byte of the last point attribute changed after export.
  std::ifstream in(dir / "m.vdb", std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  bytes[bytes.size() - 3] ^= 0x10;
  std::ofstream(dir / "bad.vdb", std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  expect_refused(dir / "bad.vdb", "does not match the checksum hisnegs wrote");
}

// The checksum is unkeyed: an edited points grid can carry a recomputed one. Such a
// file must still be read only as far as the walk checked it: every edit of the
// grid's bytes (every 31st byte; two patterns), its checksum rewritten to match, is
// imported, described or refused with an InputError, never a crash inside OpenVDB
// (its asserts on page sizes, array lengths, voxel offsets; thread creation or an
// allocation failing under VdbReadGuard's cap). Before the walk covered point
// buffers, 59 of 786 such edits of a 59-Gaussian file (every 61st byte) aborted.
TEST(ExportVdb, EditedPointGridsWithRecomputedChecksumsAreReadOrRefused) {
  ScratchDir dir;
  VdbExportOptions options;
  options.points = true;
  export_vdb(dir / "m.vdb", Checkpoint{random_mixture(20, 12), stack_meta()}, VoxelLattice::of(kFrame), options,
             "m.ply");
  const io::VdbFileCheck check = io::check_vdb_structure(dir / "m.vdb");
  const io::VdbGridCheck* points = io::find_grid(check, "gaussians");
  ASSERT_TRUE(points);
  ASSERT_GE(check.checksums_pos, 0);
  std::ifstream in(dir / "m.vdb", std::ios::binary);
  const std::vector<char> good((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const fs::path bad = dir / "bad.vdb";
  int read = 0, refused = 0;
  for (std::int64_t at = points->grid_pos; at < points->end_pos; at += 31) {
    for (const unsigned char x : {0x01, 0xFF}) {
      std::vector<char> b = good;
      b[static_cast<std::size_t>(at)] = static_cast<char>(b[static_cast<std::size_t>(at)] ^ x);
      std::ofstream(bad, std::ios::binary).write(b.data(), static_cast<std::streamsize>(b.size()));
      const std::optional<std::string> sums = io::vdb_grid_checksums(bad, check);  // same grid ranges
      ASSERT_TRUE(sums);
      std::memcpy(b.data() + check.checksums_pos, sums->data(), sums->size());
      std::ofstream(bad, std::ios::binary).write(b.data(), static_cast<std::streamsize>(b.size()));
      try {
        (void)import_vdb_points(bad);
        ++read;
      } catch (const io::InputError& e) {
        ++refused;
        EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      }
      try {
        (void)io::inspect_vdb(bad);
      } catch (const io::InputError&) {
      }
    }
  }
  EXPECT_GT(read, 0);  // attribute values and metadata strings: read (and checked by the checkpoint reader)
  EXPECT_GT(refused, 0);
}

TEST(ExportVdb, RejectsBadOptionsAndLeavesNoFile) {
  ScratchDir dir;
  const Checkpoint cp{random_mixture(2, 8), {}};
  const auto rejected = [&](const VoxelLattice& lattice, const VdbExportOptions& o, const std::string& needle) {
    try {
      export_vdb(dir / "x.vdb", cp, lattice, o, "m.ply");
      ADD_FAILURE() << needle << ": accepted";
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
    EXPECT_TRUE(dir.entries().empty()) << needle << ": a file was left behind";
  };
  VdbExportOptions o;
  rejected(VoxelLattice::aligned(0.0), o, "voxel size 0");
  rejected(VoxelLattice::aligned(-0.5), o, "voxel size -0.5");
  rejected(VoxelLattice::aligned(std::nan("")), o, "voxel size nan");
  o.cutoff = 0.0;
  rejected(VoxelLattice::aligned(0.1), o, "cutoff = 0");
  o = VdbExportOptions{};
  o.support = 0.0;
  rejected(VoxelLattice::aligned(0.1), o, "support = 0");
  o = VdbExportOptions{};
  o.tail = 2 * o.cutoff;
  rejected(VoxelLattice::aligned(0.1), o, "tail = ");
  // Far too fine: refused before anything is allocated (the supports would reach
  // ~1e10 leaves each), and below what an OpenVDB transform can hold (det < 3e-15).
  // The limit is set: on a machine with 125 GiB available the first case fitted
  // under the default one, and the test was killed allocating it (the H200 machine).
  {
    const testing::ScopedEnv limit("HISNEGS_MAX_ALLOC_GB", "16");
    rejected(VoxelLattice::aligned(1e-4), VdbExportOptions{}, "GiB available); use a larger voxel size");
  }
  rejected(VoxelLattice::aligned(1e-6), VdbExportOptions{}, "too small for an OpenVDB transform");
}

TEST(ExportVdb, ModelFrameAndWorldBoxCheck) {
  const CheckpointMeta meta = stack_meta();
  const std::optional<io::WorldFrame> frame = model_frame(meta);
  ASSERT_TRUE(frame.has_value());
  EXPECT_EQ(frame->shape(), Eigen::Vector3i(40, 40, 20));
  EXPECT_EQ(frame->aspect(), Eigen::Vector3d(1.0, 1.0, 0.5));
  EXPECT_FALSE(model_frame(CheckpointMeta{}).has_value());
  EXPECT_NO_THROW(require_same_world_box(meta, kFrame, "s.tif"));
  EXPECT_NO_THROW(require_same_world_box(CheckpointMeta{}, kFrame, "s.tif"));
  EXPECT_THROW(require_same_world_box(meta, io::WorldFrame(40, 40, 20, Eigen::Vector3d(1, 1, 1)), "s.tif"),
               io::InputError);
}

TEST(ExportFormats, SplatPlyMapsEveryGaussianOntoViewerFields) {
  const GaussianMixture m = random_mixture(5, 9);
  const io::PlyTable t = splat_ply_table(m, SplatPlyOptions{});
  const io::PlyElement* v = t.find("vertex");
  ASSERT_NE(v, nullptr);
  ASSERT_EQ(v->count(), 5);
  std::vector<std::string> names;
  for (const auto& p : v->properties()) names.push_back(p.name);
  const std::vector<std::string> expect = {"x",       "y",      "z",      "nx",      "ny",      "nz",
                                           "f_dc_0",  "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                                           "scale_2", "rot_0",  "rot_1",  "rot_2",   "rot_3"};
  EXPECT_EQ(names, expect);
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto row = static_cast<std::int64_t>(k);
    const auto val = [&](const char* name) { return v->value(row, *v->find_property(name)); };
    EXPECT_EQ(val("x"), m[k].mean[0]);
    EXPECT_EQ(val("z"), m[k].mean[2]);
    EXPECT_EQ(val("opacity"), m[k].intensity_logit);  // viewers: alpha = sigmoid(opacity)
    EXPECT_EQ(val("scale_1"), m[k].log_scale[1]);     // viewers: σ = exp(scale)
    EXPECT_EQ(val("rot_0"), m[k].rotation[0]);        // w first, as 3DGS stores it
    EXPECT_EQ(val("rot_3"), m[k].rotation[3]);
    EXPECT_EQ(val("nx"), 0.0);
    // The viewer's colour 0.5 + C0 f_dc is the intensity a (grey), to float precision.
    for (const char* dc : {"f_dc_0", "f_dc_1", "f_dc_2"}) {
      EXPECT_NEAR(0.5 + kShC0 * val(dc), intensity<double>(m[k]), 1e-6);
    }
  }
  SplatPlyOptions rest;
  rest.sh_rest = true;
  const io::PlyTable rest_table = splat_ply_table(m, rest);  // kept alive: find() points into it
  const io::PlyElement* r = rest_table.find("vertex");
  ASSERT_NE(r, nullptr);
  EXPECT_EQ(r->properties().size(), 62u);  // the reference 3DGS layout at SH degree 3
  EXPECT_EQ(r->properties()[9].name, "f_rest_0");
  EXPECT_EQ(r->properties()[54].name, "opacity");
}

TEST(ExportFormats, FireColormapRampsBlackRedYellowWhite) {
  using A = std::array<double, 3>;
  EXPECT_EQ(splat_color(0.0, SplatColormap::kFire), (A{0, 0, 0}));
  EXPECT_EQ(splat_color(0.5, SplatColormap::kFire), (A{1, 0.5, 0}));
  EXPECT_EQ(splat_color(1.0, SplatColormap::kFire), (A{1, 1, 1}));
  EXPECT_EQ(splat_color(0.25, SplatColormap::kGrey), (A{0.25, 0.25, 0.25}));
}

TEST(ExportFormats, DenseResamplingMatchesDirectEvaluation) {
  const GaussianMixture m = random_mixture(20, 10);
  const MixtureModel model;  // a sum with the default support δ
  const std::vector<float> f = rasterize_dense(m, model, kFrame, VdbExportOptions{}.tail);
  const std::vector<float> all = rasterize_dense(m, model, kFrame, VdbExportOptions{}.tail, /*untruncated_sum=*/true);
  ASSERT_EQ(f.size(), 40u * 40u * 20u);
  const SoftmaxReference fitted(m, 1.0, model.cutoff);
  double max_diff = 0, max_all_diff = 0;
  for (int z = 0; z < 20; ++z)
    for (int y = 0; y < 40; ++y)
      for (int x = 0; x < 40; ++x) {
        const Eigen::Vector3d w = kFrame.world_from_index(Eigen::Vector3d(x, y, z));
        const std::size_t i = (static_cast<std::size_t>(z) * 40 + y) * 40 + x;
        max_diff = std::max(max_diff, std::abs(f[i] - fitted.sum(w)));
        max_all_diff = std::max(max_all_diff, std::abs(all[i] - evaluate_mixture(m, w)));
      }
  EXPECT_LT(max_diff, 1e-5);
  EXPECT_LT(max_all_diff, 1e-5);
}

TEST(ExportFormats, DenseSoftmaxIsTheModelsOwnF) {
  const Checkpoint cp = softmax_checkpoint();
  const std::vector<float> f = rasterize_dense(cp.mixture, model_of(cp.meta, 16.0), kFrame, VdbExportOptions{}.tail);
  ASSERT_EQ(f.size(), 40u * 40u * 20u);
  const SoftmaxGaps gaps = gaps_to_softmax(
      cp.mixture, 0.0, [&](int x, int y, int z) { return f[(static_cast<std::size_t>(z) * 40 + y) * 40 + x]; });
  EXPECT_LT(gaps.max_diff, 1e-5);
  EXPECT_GT(gaps.max_sum_gap, 0.1);
}

}  // namespace
}  // namespace hisnegs::gmf
