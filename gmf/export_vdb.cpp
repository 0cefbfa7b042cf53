// SPDX-License-Identifier: Apache-2.0
// export_vdb: per-Gaussian supports -> (leaf, Gaussian) pairs -> per-leaf evaluation
// of f with TBB -> `density` FloatGrid; the `gaussians` PointDataGrid written with
// openvdb::points and read back by import_vdb_points.
#include "gmf/export_vdb.hpp"

#include <openvdb/io/File.h>
#include <openvdb/points/PointAttribute.h>
#include <openvdb/points/PointConversion.h>
#include <openvdb/points/PointCount.h>
#include <openvdb/points/PointDataGrid.h>
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <vector>

#include "gmf/core/rasterize.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/timer.hpp"
#include "io/vdb_file.hpp"

namespace hisnegs::gmf {
namespace fs = std::filesystem;

using openvdb::Coord;
using openvdb::FloatGrid;
using LeafT = openvdb::FloatTree::LeafNodeType;
using openvdb::points::PointDataGrid;

namespace {

// The rasterizer's blocks are OpenVDB leaves, offsets included (block_offset is
// LeafNode::coordToOffset: z fastest).
static_assert(LeafT::LOG2DIM == kRasterBlockLog2 && LeafT::SIZE == kRasterBlockVoxels);

constexpr const char* kDensityGrid = "density";
constexpr const char* kPointsGrid = "gaussians";
constexpr const char* kCheckpointMetaKey = "hisnegs_checkpoint";
constexpr int kVdbFormatVersion = 1;

// The `density` grid: the core rasterizer's blocks are OpenVDB leaves (8³ voxels,
// the same z-fastest offsets), evaluated in parallel; a leaf is kept where some f
// exceeds the cutoff.
FloatGrid::Ptr rasterize_density(const GaussianMixture& mixture, const MixtureModel& mixture_model,
                                 const VoxelLattice& lattice, const VdbExportOptions& options, const std::string& model,
                                 const ExportProgress& progress, VdbExportReport& report) {
  const BlockRasterizer raster(mixture, lattice,
                               RasterizeOptions::exported(mixture_model, options.tail, options.untruncated_sum), model);
  const std::size_t n_leaves = raster.blocks();
  report.candidate_leaves = static_cast<std::int64_t>(n_leaves);
  std::vector<std::unique_ptr<LeafT>> leaves(n_leaves);  // empty where nothing exceeds the cutoff
  std::atomic<std::int64_t> done{0};
  std::mutex progress_mutex;
  const std::int64_t step = std::max<std::int64_t>(1, static_cast<std::int64_t>(n_leaves) / 20);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n_leaves, 4), [&](const auto& r) {
    BlockValues acc;
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      raster.evaluate(i, acc);
      const Eigen::Vector3i o = raster.block_origin(i);
      std::unique_ptr<LeafT>& leaf = leaves[i];
      for (openvdb::Index n = 0; n < LeafT::SIZE; ++n) {
        if (!(acc[n] > options.cutoff)) continue;
        if (!leaf) leaf = std::make_unique<LeafT>(Coord(o.x(), o.y(), o.z()), 0.0f, false);
        leaf->setValueOn(n, static_cast<float>(acc[n]));
      }
      const std::int64_t d = ++done;
      if (progress && d % step == 0) {
        const std::lock_guard<std::mutex> lock(progress_mutex);
        progress(d, static_cast<std::int64_t>(n_leaves));
      }
    }
  });
  FloatGrid::Ptr grid = FloatGrid::create(0.0f);
  for (std::unique_ptr<LeafT>& leaf : leaves) {
    if (leaf) grid->tree().addLeaf(leaf.release());  // the tree takes ownership
  }
  return grid;
}

openvdb::Vec3d vdb_vec(const std::array<double, 3>& v) { return {v[0], v[1], v[2]}; }

void put_density_meta(FloatGrid& g, const Checkpoint& checkpoint, const VoxelLattice& lattice,
                      const VdbExportOptions& options, const std::string& model_source) {
  const CheckpointMeta& m = checkpoint.meta;
  g.insertMeta("hisnegs_format_version", openvdb::Int32Metadata(kVdbFormatVersion));
  g.insertMeta("gaussians", openvdb::Int64Metadata(static_cast<openvdb::Int64>(checkpoint.mixture.size())));
  g.insertMeta("cutoff", openvdb::DoubleMetadata(options.cutoff));
  g.insertMeta("tail", openvdb::DoubleMetadata(options.tail));
  const bool soft = checkpoint.meta.aggregation == Aggregation::kSoftmax;
  const Aggregation aggregation = checkpoint.meta.aggregation;
  g.insertMeta("aggregation", openvdb::StringMetadata(soft                                  ? "softmax"
                                                      : aggregation == Aggregation::kMax ? "max"
                                                                                          : "sum"));
  if (soft) g.insertMeta("beta", openvdb::DoubleMetadata(checkpoint.meta.beta));
  const bool untruncated = aggregation == Aggregation::kSum && options.untruncated_sum;
  g.insertMeta("untruncated_sum", openvdb::BoolMetadata(untruncated));
  if (!untruncated) g.insertMeta("support", openvdb::DoubleMetadata(options.support));
  g.insertMeta("model", openvdb::StringMetadata(model_source));
  std::string source;
  for (const auto& [key, value] : m.extra) {
    if (key == "source") source = value;
  }
  g.insertMeta("source", openvdb::StringMetadata(source));
  if (m.volume_shape_zyx) {
    const auto& s = *m.volume_shape_zyx;
    g.insertMeta("volume_shape_xyz", openvdb::Vec3IMetadata(openvdb::Vec3i(s[2], s[1], s[0])));
  }
  if (m.spacing_um) g.insertMeta("spacing_um", openvdb::Vec3DMetadata(vdb_vec(*m.spacing_um)));
  if (m.aspect) g.insertMeta("aspect", openvdb::Vec3DMetadata(vdb_vec(*m.aspect)));
  if (!m.normalization.empty()) g.insertMeta("normalization", openvdb::StringMetadata(m.normalization));
  if (lattice.clip) {
    const auto& c = *lattice.clip;
    g.insertMeta("clip_min", openvdb::Vec3IMetadata(openvdb::Vec3i(c.min.x(), c.min.y(), c.min.z())));
    g.insertMeta("clip_max", openvdb::Vec3IMetadata(openvdb::Vec3i(c.max.x(), c.max.y(), c.max.z())));
  }
}

// Attribute layout of the `gaussians` grid, one place for writer and reader.
constexpr const char* kMeanAttr = "mean";
constexpr const char* kLogScaleAttr = "log_scale";
constexpr const char* kRotationAttr = "rotation";
constexpr const char* kLogitAttr = "intensity_logit";
constexpr const char* kIntensityAttr = "intensity";
constexpr const char* kIdAttr = "id";

// Every Gaussian as one point at its mean: `P` (OpenVDB's own position, for viewers),
// the exact parameters as uncompressed float attributes, a = sigmoid(logit) for
// display, and `id` (its checkpoint row: points are stored in voxel order).
PointDataGrid::Ptr make_points(const Checkpoint& checkpoint, const openvdb::math::Transform& transform) {
  namespace vp = openvdb::points;
  const GaussianMixture& mixture = checkpoint.mixture;
  const std::size_t K = mixture.size();
  if (K > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    throw std::invalid_argument("export vdb --points: " + std::to_string(K) + " Gaussians exceed the int32 `id`");
  }
  std::vector<openvdb::Vec3d> position(K);
  std::vector<openvdb::Vec3f> mean(K), log_scale(K);
  std::vector<float> rotation(4 * K), logit(K), intensity(K);
  std::vector<std::int32_t> id(K);
  for (std::size_t k = 0; k < K; ++k) {
    const GaussianParams& g = mixture[k];
    position[k] = openvdb::Vec3d(g.mean[0], g.mean[1], g.mean[2]);
    mean[k] = openvdb::Vec3f(g.mean[0], g.mean[1], g.mean[2]);
    log_scale[k] = openvdb::Vec3f(g.log_scale[0], g.log_scale[1], g.log_scale[2]);
    for (int c = 0; c < 4; ++c) rotation[4 * k + c] = g.rotation[c];
    logit[k] = g.intensity_logit;
    intensity[k] = static_cast<float>(sigmoid(static_cast<double>(g.intensity_logit)));
    id[k] = static_cast<std::int32_t>(k);
  }
  const vp::PointAttributeVector<openvdb::Vec3d> positions(position);
  const auto index_grid = openvdb::tools::createPointIndexGrid<openvdb::tools::PointIndexGrid>(positions, transform);
  PointDataGrid::Ptr grid = vp::createPointDataGrid<vp::NullCodec, PointDataGrid>(*index_grid, positions, transform);
  auto& tree = grid->tree();
  const auto& index_tree = index_grid->tree();
  // NullCodec everywhere: the stored floats are the checkpoint's, bit for bit.
  vp::appendAttribute<openvdb::Vec3f, vp::NullCodec>(tree, kMeanAttr);
  vp::populateAttribute(tree, index_tree, kMeanAttr, vp::PointAttributeVector<openvdb::Vec3f>(mean));
  vp::appendAttribute<openvdb::Vec3f, vp::NullCodec>(tree, kLogScaleAttr);
  vp::populateAttribute(tree, index_tree, kLogScaleAttr, vp::PointAttributeVector<openvdb::Vec3f>(log_scale));
  vp::appendAttribute<float, vp::NullCodec>(tree, kRotationAttr, 0.0f, /*stride=*/4);
  vp::populateAttribute(tree, index_tree, kRotationAttr, vp::PointAttributeVector<float>(rotation, 4), 4);
  vp::appendAttribute<float, vp::NullCodec>(tree, kLogitAttr);
  vp::populateAttribute(tree, index_tree, kLogitAttr, vp::PointAttributeVector<float>(logit));
  vp::appendAttribute<float, vp::NullCodec>(tree, kIntensityAttr);
  vp::populateAttribute(tree, index_tree, kIntensityAttr, vp::PointAttributeVector<float>(intensity));
  vp::appendAttribute<std::int32_t, vp::NullCodec>(tree, kIdAttr);
  vp::populateAttribute(tree, index_tree, kIdAttr, vp::PointAttributeVector<std::int32_t>(id));

  // The checkpoint's own header lines, so that import restores its metadata exactly.
  std::string header;
  for (const std::string& line : checkpoint_to_ply(GaussianMixture{}, checkpoint.meta).comments) {
    header += (header.empty() ? "" : "\n") + line;
  }
  grid->setName(kPointsGrid);
  grid->insertMeta(kCheckpointMetaKey, openvdb::StringMetadata(header));
  grid->insertMeta("hisnegs_format_version", openvdb::Int32Metadata(kVdbFormatVersion));
  grid->insertMeta("gaussians", openvdb::Int64Metadata(static_cast<openvdb::Int64>(K)));
  return grid;
}

}  // namespace

void VdbExportOptions::validate() const {
  if (!(cutoff > 0.0 && cutoff < 1.0)) {
    throw io::InputError("cutoff = " + io::number_text(cutoff) + ": must be in (0, 1) (normalized intensity)");
  }
  if (!(std::isfinite(support) && support > 0.0)) {
    throw io::InputError("support = " + io::number_text(support) + ": must be a finite number > 0 (Mahalanobis δ)");
  }
  if (!(tail > 0.0 && tail <= cutoff)) {
    throw io::InputError("tail = " + io::number_text(tail) + ": must be in (0, cutoff = " + io::number_text(cutoff) +
                         "]");
  }
}

VdbExportReport export_vdb(const fs::path& path, const Checkpoint& checkpoint, const VoxelLattice& lattice,
                           const VdbExportOptions& options, const std::string& model_source,
                           const ExportProgress& progress) {
  options.validate();
  lattice.validate();
  io::ensure_openvdb_initialized();
  VdbExportReport report;
  report.gaussians = static_cast<std::int64_t>(checkpoint.mixture.size());
  io::Stopwatch watch;

  const auto transform = io::make_vdb_transform(lattice.voxel_size_world, lattice.origin_world);
  FloatGrid::Ptr density = rasterize_density(checkpoint.mixture, model_of(checkpoint.meta, options.support), lattice,
                                             options, model_source, progress, report);
  density->setTransform(transform->copy());
  density->setName(kDensityGrid);
  density->setGridClass(openvdb::GRID_FOG_VOLUME);
  put_density_meta(*density, checkpoint, lattice, options, model_source);
  report.leaf_count = static_cast<std::int64_t>(density->tree().leafCount());
  report.active_voxels = static_cast<std::int64_t>(density->activeVoxelCount());
  report.grid_memory_bytes = static_cast<std::size_t>(density->memUsage());
  report.rasterize_seconds = watch.lap();

  openvdb::GridPtrVec grids{density};
  if (options.points) {
    PointDataGrid::Ptr points = make_points(checkpoint, *transform);
    report.grid_memory_bytes += static_cast<std::size_t>(points->memUsage());
    grids.push_back(points);
    report.points_seconds = watch.lap();
  }

  io::write_vdb_file(path, grids);
  report.write_seconds = watch.lap();
  report.file_bytes = fs::file_size(path);
  return report;
}

namespace {

// The attribute `name` of a points leaf, checked to hold T with `stride` values per point.
const openvdb::points::AttributeArray& attribute(const openvdb::points::PointDataTree::LeafNodeType& leaf,
                                                 const fs::path& path, const char* name, const std::string& type,
                                                 openvdb::Index stride) {
  const std::size_t pos = leaf.attributeSet().find(name);
  if (pos == openvdb::points::AttributeSet::INVALID_POS) {
    io::fail_input(path, "grid 'gaussians' lacks point attribute '" + std::string(name) + "' (" + type +
                             ", written by hisnegs export vdb --points)");
  }
  const openvdb::points::AttributeArray& array = leaf.constAttributeArray(pos);
  if (array.valueType() != type || array.stride() != stride) {
    io::fail_input(path, "point attribute '" + std::string(name) + "' holds " + array.valueType() + " × " +
                             std::to_string(array.stride()) + ", expected " + type + " × " + std::to_string(stride));
  }
  return array;
}

}  // namespace

namespace {

// The grid 'gaussians' of a file `export vdb --points` wrote, its bytes checked first.
PointDataGrid::Ptr read_points_grid(const fs::path& path) {
  io::require_regular_file(path);
  io::ensure_openvdb_initialized();
  const io::VdbFileCheck check = io::check_vdb_structure(path);
  const io::VdbGridCheck* points = io::find_grid(check, kPointsGrid);
  if (!points) io::fail_input(path, "has no grid named 'gaussians' (export it with hisnegs export vdb --points)");
  // Integrity: the bytes hisnegs wrote (attribute values the walk cannot judge).
  // The checksum is unkeyed, so it is no licence to read: that is the walk's alone.
  if (!points->checksum_match.value_or(false)) {
    io::fail_input(path, points->checksum_match
                             ? "grid 'gaussians' does not match the checksum hisnegs wrote for it: the file was "
                               "changed or damaged after export"
                             : "grid 'gaussians' carries no hisnegs checksum (written by another tool or an older "
                               "hisnegs): export it again with hisnegs export vdb --points");
  }
  // Point attributes state their own sizes (descriptor, array lengths, pages): OpenVDB
  // allocates and asserts by them as found, so every one must have passed the walk.
  if (!io::values_checked(check, kPointsGrid)) {
    io::fail_input(path, "grid 'gaussians' is stored in a layout hisnegs cannot check (" +
                             io::printable(points->grid_type, 64) +
                             "): export it again with hisnegs export vdb --points");
  }
  io::VdbReadGuard guard(path);
  PointDataGrid::Ptr grid;
  try {
    guard.run([&] {
      openvdb::io::File file(path.string());
      file.open(false);
      grid = openvdb::gridPtrCast<PointDataGrid>(file.readGrid(kPointsGrid));
      file.close();
    });
  } catch (const openvdb::Exception& e) {
    io::fail_input(path, "not a readable OpenVDB file: " + io::printable(e.what()));  // OpenVDB messages can span lines
  } catch (const std::bad_alloc&) {
    io::fail_input(path, "damaged: reading it would take more than " + io::gib_text(guard.cap_bytes()) +
                             " of memory (64x the file, at least 1 GiB)");
  }
  if (!grid) io::fail_input(path, "grid 'gaussians' is not a PointDataGrid");
  return grid;
}

// The number of points, each leaf's voxel offsets checked first against its
// attribute arrays (PointDataLeafNode::validateOffsets: non-decreasing, the last
// one the arrays' common length). OpenVDB reads the offsets as found, so an index
// past an array would trip its assert (or read past it). K then counts values really
// read: a leaf's 'id' array must exist, and be uniform (one stored value) for one
// point at most, before K sizes anything.
std::size_t validated_point_count(const PointDataGrid& grid, const fs::path& path) {
  std::size_t K = 0;
  try {
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
      leaf->validateOffsets();
      const auto n = static_cast<std::size_t>(leaf->pointCount());
      if (n == 0) continue;
      const std::size_t pos = leaf->attributeSet().find(kIdAttr);
      if (pos == openvdb::points::AttributeSet::INVALID_POS) {
        io::fail_input(path,
                       "grid 'gaussians' lacks point attribute 'id' (int32, written by hisnegs export vdb "
                       "--points)");
      }
      if (n > 1 && leaf->constAttributeArray(pos).isUniform())
        io::fail_input(path, "point attribute 'id' holds one value for " + std::to_string(n) + " points");
      K += n;
    }
  } catch (const openvdb::Exception& e) {
    io::fail_input(path, "cannot read grid 'gaussians': " + io::printable(e.what()));
  }
  return K;
}

// The K Gaussians of the grid's points, placed by their 'id' attribute (each of
// 0..K-1 once).
GaussianMixture gaussians_of_points(const PointDataGrid& grid, std::size_t K, const fs::path& path) {
  namespace vp = openvdb::points;
  GaussianMixture mixture;
  mixture.resize(K);
  std::vector<char> seen(K, 0);
  const std::string vec3 = openvdb::typeNameAsString<openvdb::Vec3f>();
  const std::string real = openvdb::typeNameAsString<float>();
  const std::string int32 = openvdb::typeNameAsString<std::int32_t>();
  try {
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
      const vp::AttributeHandle<openvdb::Vec3f> mean(attribute(*leaf, path, kMeanAttr, vec3, 1));
      const vp::AttributeHandle<openvdb::Vec3f> log_scale(attribute(*leaf, path, kLogScaleAttr, vec3, 1));
      const vp::AttributeHandle<float> rotation(attribute(*leaf, path, kRotationAttr, real, 4));
      const vp::AttributeHandle<float> logit(attribute(*leaf, path, kLogitAttr, real, 1));
      const vp::AttributeHandle<std::int32_t> id(attribute(*leaf, path, kIdAttr, int32, 1));
      for (auto index = leaf->beginIndexAll(); index; ++index) {
        const openvdb::Index n = *index;
        const std::int32_t k = id.get(n);
        if (k < 0 || static_cast<std::size_t>(k) >= K || seen[k]) {
          io::fail_input(path,
                         "point attribute 'id' = " + std::to_string(k) + " is " +
                             (k < 0 || static_cast<std::size_t>(k) >= K ? "outside 0.." + std::to_string(K) + " - 1"
                                                                        : std::string("given twice")) +
                             " (ids must number the " + std::to_string(K) + " points 0..K-1 once each)");
        }
        seen[k] = 1;
        GaussianParams& g = mixture[static_cast<std::size_t>(k)];
        const openvdb::Vec3f m = mean.get(n), s = log_scale.get(n);
        g.mean = {m.x(), m.y(), m.z()};
        g.log_scale = {s.x(), s.y(), s.z()};
        for (openvdb::Index c = 0; c < 4; ++c) g.rotation[c] = rotation.get(n, c);
        g.intensity_logit = logit.get(n);
      }
    }
  } catch (const openvdb::Exception& e) {
    io::fail_input(path, "cannot read grid 'gaussians': " + io::printable(e.what()));
  }
  return mixture;
}

}  // namespace

Checkpoint import_vdb_points(const fs::path& path) {
  const PointDataGrid::Ptr grid = read_points_grid(path);
  const auto header = grid->getMetadata<openvdb::StringMetadata>(kCheckpointMetaKey);
  if (!header) {
    io::fail_input(
        path, "grid 'gaussians' lacks metadata '" + std::string(kCheckpointMetaKey) + "' (not written by hisnegs?)");
  }
  const std::size_t K = validated_point_count(*grid, path);
  if (const auto count = grid->getMetadata<openvdb::Int64Metadata>("gaussians");
      count && count->value() != static_cast<openvdb::Int64>(K)) {
    io::fail_input(path, "grid 'gaussians' holds " + std::to_string(K) + " points but its metadata 'gaussians' says " +
                             std::to_string(count->value()));
  }
  const GaussianMixture mixture = gaussians_of_points(*grid, K, path);
  // Through the checkpoint's own reader: the same checks (finite values, non-zero
  // quaternions, well-formed metadata) as loading a .ply, with this file named.
  io::PlyTable table;
  std::istringstream lines(header->value());
  for (std::string line; std::getline(lines, line);) table.comments.push_back(line);
  io::PlyElement vertex("vertex", static_cast<std::int64_t>(K), checkpoint_properties());
  static_assert(sizeof(GaussianParams) == kGaussianParamCount * sizeof(float));
  if (K > 0) std::memcpy(vertex.bytes().data(), mixture.data(), vertex.bytes().size());
  table.elements.push_back(std::move(vertex));
  return checkpoint_from_ply(table, path);
}

}  // namespace hisnegs::gmf
