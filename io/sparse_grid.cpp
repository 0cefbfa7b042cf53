// SPDX-License-Identifier: Apache-2.0
// Building io::SparseGrid from a dense volume (parallel over 8^3 bricks, OpenVDB
// dilation), .vdb read/write with hisnegs metadata, and inspect_vdb.
#include "io/sparse_grid.hpp"

#include <openvdb/io/File.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <sys/resource.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <fstream>
#include <mutex>
#include <random>
#include <sstream>

#include "io/atomic_file.hpp"
#include "io/config.hpp"
#include "io/detail/vdb_grids.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/vdb_file.hpp"
#include "io/vdb_validate.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::io {

using openvdb::Coord;
using openvdb::FloatGrid;
using openvdb::FloatTree;
using LeafT = FloatTree::LeafNodeType;
constexpr int kLeafDim = static_cast<int>(LeafT::DIM);  // 8

void SparseGridOptions::validate() const {
  require_in_range("sparse_grid", "threshold", threshold, 0.0, 0.999999);
  require_in_range("sparse_grid", "band_voxels", band_voxels, 0, 32);
  require_in_range("sparse_grid", "background_fraction", background_fraction, 0.0, 1.0);
}

void ensure_openvdb_initialized() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

VdbFileCheck check_vdb_structure(const std::filesystem::path& path) {
  ensure_openvdb_initialized();
  return validate_vdb_file(path, [](const std::string& type) { return openvdb::Metadata::isRegisteredType(type); });
}

#if defined(__SANITIZE_ADDRESS__)
#define HISNEGS_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define HISNEGS_ASAN 1
#endif
#endif

VdbReadGuard::VdbReadGuard(const std::filesystem::path& path) {
  arena_.initialize();  // its allocations made before the cap, not under it
  std::error_code ec;
  const double file_bytes = static_cast<double>(std::filesystem::file_size(path, ec));
  cap_ = std::min(allocation_limit_bytes(), std::max(double(1u << 30), 64.0 * (ec ? 0.0 : file_bytes)));
#ifndef HISNEGS_ASAN
  struct rlimit lim {};
  if (::getrlimit(RLIMIT_AS, &lim) != 0) return;
  std::ifstream statm("/proc/self/statm");
  unsigned long long pages = 0;
  if (!(statm >> pages)) return;
  const double used = static_cast<double>(pages) * static_cast<double>(::sysconf(_SC_PAGESIZE));
  const double wanted = used + cap_;
  if (lim.rlim_cur != RLIM_INFINITY && static_cast<double>(lim.rlim_cur) <= wanted) return;  // already tighter
  previous_soft_ = lim.rlim_cur;
  lim.rlim_cur = static_cast<rlim_t>(wanted);
  if (lim.rlim_max != RLIM_INFINITY && lim.rlim_cur > lim.rlim_max) return;
  active_ = ::setrlimit(RLIMIT_AS, &lim) == 0;
#endif
}

VdbReadGuard::~VdbReadGuard() {
  if (!active_) return;
  struct rlimit lim {};
  if (::getrlimit(RLIMIT_AS, &lim) != 0) return;
  lim.rlim_cur = static_cast<rlim_t>(previous_soft_);
  ::setrlimit(RLIMIT_AS, &lim);
}

namespace {
// io::File::write writes through its own std::ofstream and never looks at the
// stream's state afterwards, so a full disk went unnoticed. This archive writes the
// same seekable .vdb layout (Archive::write, as File::write does) into a stream we
// own and check.
class CheckedVdbArchive final : public openvdb::io::Archive {
 public:
  openvdb::io::Archive::Ptr copy() const override { return std::make_shared<CheckedVdbArchive>(*this); }
  void write_to(std::ostream& os, const openvdb::GridPtrVec& grids, const openvdb::MetaMap& file_meta) const {
    openvdb::io::Archive::write(os, grids, /*seekable=*/true, file_meta);
  }
};
}  // namespace

void write_vdb_file(const std::filesystem::path& path, const openvdb::GridPtrVec& grids) {
  AtomicFile out(path);
  {
    std::ofstream os(out.temp_path(), std::ios::binary | std::ios::trunc);
    if (!os) fail_write(path, errno);
    errno = 0;  // a failing write(2) inside the stream leaves its errno (ENOSPC, EIO, EFBIG)
    // Room for every grid's checksum, filled in below once the grids' bytes exist.
    openvdb::MetaMap file_meta;
    file_meta.insertMeta(kVdbChecksumKey, openvdb::StringMetadata(std::string(16 * grids.size(), '0')));
    try {
      CheckedVdbArchive archive;
      archive.setCompression(openvdb::io::COMPRESS_BLOSC);
      archive.write_to(os, grids, file_meta);
    } catch (const openvdb::Exception& e) {
      throw std::runtime_error(path.string() + ": cannot write VDB: " + printable(e.what()));
    }
    if (!os) fail_write(path, errno);
    os.flush();
    if (!os) fail_write(path, errno);
    os.close();
    if (!os) fail_write(path, errno);
  }
  // The walk checks what was written and finds each grid's bytes and the room left
  // for their checksums.
  const VdbFileCheck check = check_vdb_structure(out.temp_path());
  if (check.checksums_pos < 0 || check.checksums.size() != 16 * check.grids.size())
    throw std::runtime_error(path.string() + ": cannot write VDB: no room for the grid checksums");
  errno = 0;
  const std::optional<std::string> checksums = vdb_grid_checksums(out.temp_path(), check);
  if (!checksums) fail_write(path, errno);
  std::fstream patch(out.temp_path(), std::ios::binary | std::ios::in | std::ios::out);
  patch.seekp(check.checksums_pos);
  patch.write(checksums->data(), static_cast<std::streamsize>(checksums->size()));
  patch.flush();
  if (!patch) fail_write(path, errno);
  patch.close();
  if (!patch) fail_write(path, errno);
  out.commit();
}

openvdb::math::Transform::Ptr make_vdb_transform(const Eigen::Vector3d& s, const Eigen::Vector3d& o) {
  // OpenVDB maps row vectors: world = [i j k 1] * M, so the scale sits on the
  // diagonal and the translation in the last row. world = scale * index + offset.
  const openvdb::math::Mat4d m(s.x(), 0.0, 0.0, 0.0,  //
                               0.0, s.y(), 0.0, 0.0,  //
                               0.0, 0.0, s.z(), 0.0,  //
                               o.x(), o.y(), o.z(), 1.0);
  try {
    return openvdb::math::Transform::createLinearTransform(m);
  } catch (const openvdb::ArithmeticError&) {
    // OpenVDB refuses maps whose determinant is nearly 0 (voxels of ~1e-5 and below).
    throw InputError("voxel size " + number_text(s.minCoeff()) +
                     " is too small for an OpenVDB transform; use a larger voxel size");
  }
}

namespace {
openvdb::math::Transform::Ptr frame_transform(const WorldFrame& frame) {
  return make_vdb_transform(frame.voxel_size(), frame.world_from_index(Eigen::Vector3d::Zero()));
}
}  // namespace

std::array<int, 9> SparseGrid::leaf_order_key(const std::array<int, 3>& o) {
  // A FloatTree's root keys its children by origin (x, then y, then z); each
  // internal node iterates its child table by offset, x-major.
  using Upper = openvdb::FloatTree::RootNodeType::ChildNodeType;
  using Lower = Upper::ChildNodeType;
  const auto level = [&](int a, int total_log2, int child_log2) {
    return total_log2 < 0 ? (o[a] >> Upper::TOTAL) : (o[a] & ((1 << total_log2) - 1)) >> child_log2;
  };
  return {level(0, -1, 0),           level(1, -1, 0),           level(2, -1, 0),
          level(0, Upper::TOTAL, Lower::TOTAL), level(1, Upper::TOTAL, Lower::TOTAL), level(2, Upper::TOTAL, Lower::TOTAL),
          level(0, Lower::TOTAL, openvdb::FloatTree::LeafNodeType::TOTAL),
          level(1, Lower::TOTAL, openvdb::FloatTree::LeafNodeType::TOTAL),
          level(2, Lower::TOTAL, openvdb::FloatTree::LeafNodeType::TOTAL)};
}

void SparseGrid::visit_active_leaves(SparseGridPart part, const LeafVisitor& visit) const {
  const openvdb::FloatGrid& grid = part == SparseGridPart::kForeground ? *impl_->volume : *impl_->background;
  std::vector<ActiveVoxel> voxels;
  voxels.reserve(LeafT::SIZE);
  for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
    if (leaf->onVoxelCount() == 0) continue;
    voxels.clear();
    for (auto v = leaf->cbeginValueOn(); v; ++v) {
      const openvdb::Coord c = v.getCoord();
      voxels.push_back({{c.x(), c.y(), c.z()}, *v});
    }
    const openvdb::Coord o = leaf->origin();
    visit({o.x(), o.y(), o.z()}, voxels);
  }
}

SparseGrid::SparseGrid() : impl_(std::make_shared<Impl>()) {
  ensure_openvdb_initialized();
  impl_->volume = FloatGrid::create(0.0f);
  impl_->background = FloatGrid::create(0.0f);
}
SparseGrid::SparseGrid(std::shared_ptr<Impl> impl) : impl_(std::move(impl)) {}

std::int64_t SparseGrid::active_voxels() const { return static_cast<std::int64_t>(impl_->volume->activeVoxelCount()); }
std::int64_t SparseGrid::background_voxels() const {
  return static_cast<std::int64_t>(impl_->background->activeVoxelCount());
}
std::int64_t SparseGrid::leaf_count() const { return static_cast<std::int64_t>(impl_->volume->tree().leafCount()); }
std::size_t SparseGrid::memory_bytes() const {
  return static_cast<std::size_t>(impl_->volume->memUsage() + impl_->background->memUsage());
}
const SparseGridMeta& SparseGrid::meta() const { return impl_->meta; }
WorldFrame SparseGrid::frame() const {
  const auto& m = impl_->meta;
  return WorldFrame(m.shape_xyz[0], m.shape_xyz[1], m.shape_xyz[2], m.aspect);
}
float SparseGrid::value(int x, int y, int z, bool* active) const {
  const auto acc = impl_->volume->getConstAccessor();
  const Coord c(x, y, z);
  if (active) *active = acc.isValueOn(c);
  return acc.getValue(c);
}

namespace {

// Voxels of the stack held in memory: `vol` holds [origin, origin + (vol.nx, vol.ny,
// vol.nz)) of the stack; the whole stack when origin is 0 and the shapes agree.
struct DenseBlock {
  const Volume& vol;
  std::array<int, 3> origin{0, 0, 0};
  [[nodiscard]] float at(int x, int y, int z) const { return vol.at(x - origin[0], y - origin[1], z - origin[2]); }
};

// The stack's 8^3 bricks (leaf units) and the range [lo, hi) of them one tile covers.
struct BrickGrid {
  int nbx, nby, nbz;
  explicit BrickGrid(const std::array<int, 3>& shape)
      : nbx((shape[0] + kLeafDim - 1) / kLeafDim),
        nby((shape[1] + kLeafDim - 1) / kLeafDim),
        nbz((shape[2] + kLeafDim - 1) / kLeafDim) {}
  [[nodiscard]] std::size_t index(int bx, int by, int bz) const {
    return (static_cast<std::size_t>(bz) * nby + by) * nbx + bx;
  }
};

// Bricks [lo, hi) (brick units) in x-fastest order, with their index in the whole stack.
struct BrickRange {
  std::array<int, 3> lo{0, 0, 0}, hi{0, 0, 0};
  [[nodiscard]] std::size_t count() const {
    return static_cast<std::size_t>(hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]);
  }
  [[nodiscard]] std::array<int, 3> brick(std::size_t i) const {
    const std::size_t nx = hi[0] - lo[0], ny = hi[1] - lo[1];
    return {lo[0] + static_cast<int>(i % nx), lo[1] + static_cast<int>((i / nx) % ny),
            lo[2] + static_cast<int>(i / (nx * ny))};
  }
  static Coord origin(const std::array<int, 3>& b) { return Coord(b[0] * kLeafDim, b[1] * kLeafDim, b[2] * kLeafDim); }
};

// Leaf holding the block's values over one brick (within the block), active where
// `keep(x, y, z, value)`. Returns nullptr when nothing in the brick is kept (no allocation).
template <class Keep>
LeafT* make_leaf(const DenseBlock& block, const Coord& origin, Keep&& keep) {
  LeafT* leaf = nullptr;
  const Volume& vol = block.vol;
  const int x0 = std::max(origin.x(), block.origin[0]), y0 = std::max(origin.y(), block.origin[1]),
            z0 = std::max(origin.z(), block.origin[2]);
  const int x1 = std::min(origin.x() + kLeafDim, block.origin[0] + vol.nx),
            y1 = std::min(origin.y() + kLeafDim, block.origin[1] + vol.ny),
            z1 = std::min(origin.z() + kLeafDim, block.origin[2] + vol.nz);
  for (int z = z0; z < z1; ++z) {
    for (int y = y0; y < y1; ++y) {
      const float* row = &vol.voxels[vol.index(0, y - block.origin[1], z - block.origin[2])];  // x = origin[0]
      for (int x = x0; x < x1; ++x) {
        const float v = row[x - block.origin[0]];
        if (!keep(x, y, z, v)) continue;
        if (!leaf) leaf = new LeafT(origin, 0.0f, false);
        leaf->setValueOn(Coord(x, y, z), v);
      }
    }
  }
  return leaf;
}

// Adds leaves made in parallel (one slot per brick) to `tree` in brick order.
void add_leaves(FloatTree& tree, std::vector<LeafT*>& leaves) {
  for (LeafT*& leaf : leaves) {
    if (leaf) tree.addLeaf(leaf);  // the tree takes ownership
    leaf = nullptr;
  }
}

// Both grids, empty, with the stack's transform.
std::shared_ptr<SparseGrid::Impl> empty_grids(const WorldFrame& frame) {
  auto impl = std::make_shared<SparseGrid::Impl>();
  const auto transform = frame_transform(frame);
  impl->volume = FloatGrid::create(0.0f);
  impl->background = FloatGrid::create(0.0f);
  for (auto* g : {impl->volume.get(), impl->background.get()}) {
    g->setTransform(transform->copy());
    g->setGridClass(openvdb::GRID_FOG_VOLUME);
  }
  impl->volume->setName("volume");
  impl->background->setName("background");
  return impl;
}

// Foreground leaves (v > threshold) of the bricks `range`, one brick per task, added
// in brick order.
void add_foreground(const DenseBlock& block, const BrickRange& range, float threshold, FloatTree& tree) {
  std::vector<LeafT*> leaves(range.count(), nullptr);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, range.count(), 16), [&](const auto& r) {
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      leaves[i] = make_leaf(block, BrickRange::origin(range.brick(i)), [&](int, int, int, float v) { return v > threshold; });
    }
  });
  add_leaves(tree, leaves);
}

// Band: OpenVDB's own morphology, then real values for the active voxels inside
// `core` (voxels [lo, hi) of the stack, within the block) and nothing outside it.
void dilate_band(const DenseBlock& block, int band_voxels, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
                 FloatTree& tree) {
  if (band_voxels > 0) {
    openvdb::tools::dilateActiveValues(tree, band_voxels, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::IGNORE_TILES);
  }
  openvdb::tree::LeafManager<FloatTree> manager(tree);
  manager.foreach ([&](LeafT& leaf, std::size_t) {
    for (auto it = leaf.beginValueOn(); it; ++it) {
      const Coord c = it.getCoord();
      if (c.x() < lo[0] || c.y() < lo[1] || c.z() < lo[2] || c.x() >= hi[0] || c.y() >= hi[1] || c.z() >= hi[2]) {
        it.setValue(0.0f);  // outside the core: the stack's edge, or another tile's voxels
        it.setValueOff();
      } else {
        it.setValue(block.at(c.x(), c.y(), c.z()));
      }
    }
  });
  openvdb::tools::pruneInactive(tree);
}

// Background subsample of the bricks `range`: Bernoulli(p) per voxel outside
// `foreground`, drawn by geometric skipping with a generator per brick of the whole
// stack (its index in `grid`), so the result depends neither on threading nor on tiles.
void add_background(const DenseBlock& block, const BrickGrid& grid, const BrickRange& range,
                    const SparseGridOptions& options, const FloatTree& foreground, FloatTree& tree) {
  const double p = options.background_fraction;
  const double log_q = std::log1p(-std::min(p, 1.0 - 1e-12));
  std::vector<LeafT*> leaves(range.count(), nullptr);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, range.count(), 16), [&](const auto& r) {
    openvdb::tree::ValueAccessor<const FloatTree> fg(foreground);
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      const std::array<int, 3> b = range.brick(i);
      std::mt19937_64 rng(options.seed * 0x9E3779B97F4A7C15ull + grid.index(b[0], b[1], b[2]));
      std::uniform_real_distribution<double> uni(0.0, 1.0);
      auto next_gap = [&]() -> long {
        if (p >= 1.0) return 0;
        return static_cast<long>(std::floor(std::log(1.0 - uni(rng)) / log_q));
      };
      long skip = next_gap();
      leaves[i] = make_leaf(block, BrickRange::origin(b), [&](int x, int y, int z, float) {
        if (fg.isValueOn(Coord(x, y, z))) return false;
        if (skip-- > 0) return false;
        skip = next_gap();
        return true;
      });
    }
  });
  add_leaves(tree, leaves);
}

// One tile: the bricks `core` (brick units) of the stack, from `block`, which holds
// the core's voxels and `band_voxels` around them (clipped to the stack). Its leaves
// join `out`'s grids; every leaf lies inside the core, so tiles never share one.
void build_tile(const DenseBlock& block, const std::array<int, 3>& shape, const BrickRange& core,
                const SparseGridOptions& options, SparseGrid::Impl& out) {
  const BrickGrid grid(shape);
  BrickRange reach;  // the bricks the block touches
  for (int a = 0; a < 3; ++a) {
    reach.lo[a] = block.origin[a] / kLeafDim;
    const int n = a == 0 ? block.vol.nx : a == 1 ? block.vol.ny : block.vol.nz;
    reach.hi[a] = (block.origin[a] + n + kLeafDim - 1) / kLeafDim;
  }
  std::array<int, 3> lo{}, hi{};  // the core's voxels, clipped to the stack
  for (int a = 0; a < 3; ++a) {
    lo[a] = core.lo[a] * kLeafDim;
    hi[a] = std::min(shape[a], core.hi[a] * kLeafDim);
  }
  FloatTree foreground(0.0f);
  add_foreground(block, reach, static_cast<float>(options.threshold), foreground);
  dilate_band(block, options.band_voxels, lo, hi, foreground);
  if (options.background_fraction > 0.0) {
    add_background(block, grid, core, options, foreground, out.background->tree());
  }
  std::vector<LeafT*> leaves;
  foreground.stealNodes(leaves);
  add_leaves(out.volume->tree(), leaves);
}

void record_meta(SparseGrid::Impl& impl, const std::array<int, 3>& shape, const VoxelSpacing& spacing,
                 const Eigen::Vector3d& aspect, const Normalization& normalization, const std::string& source,
                 const SparseGridOptions& options) {
  auto& meta = impl.meta;
  meta.shape_xyz = shape;
  meta.spacing_um = spacing.um;
  meta.aspect = aspect;
  meta.normalization = normalization;
  meta.source = source;
  meta.options = options;
}

}  // namespace

SparseGrid build_sparse_grid(const Volume& vol, const Eigen::Vector3d& aspect, const SparseGridOptions& options) {
  options.validate();
  ensure_openvdb_initialized();
  const std::array<int, 3> shape{vol.nx, vol.ny, vol.nz};
  auto impl = empty_grids(WorldFrame(vol.nx, vol.ny, vol.nz, aspect));
  const BrickGrid grid(shape);
  build_tile(DenseBlock{vol}, shape, BrickRange{{0, 0, 0}, {grid.nbx, grid.nby, grid.nbz}}, options, *impl);
  record_meta(*impl, shape, vol.spacing, aspect, vol.normalization, vol.source, options);
  return SparseGrid(std::move(impl));
}

SparseGrid build_sparse_grid(const VolumeSource& source, const Normalization& normalization,
                             const Eigen::Vector3d& aspect, const SparseGridOptions& options, int tile_voxels,
                             const std::function<void(int, int)>& on_tile,
                             const SparseGrid::LeafVisitor& take_background) {
  options.validate();
  if (tile_voxels < kLeafDim || tile_voxels % kLeafDim != 0) {
    throw std::invalid_argument("build_sparse_grid: tile_voxels " + std::to_string(tile_voxels) +
                                " is not a positive multiple of 8");
  }
  ensure_openvdb_initialized();
  const std::array<int, 3> shape{source.nx, source.ny, source.nz};
  auto impl = empty_grids(WorldFrame(source.nx, source.ny, source.nz, aspect));
  const BrickGrid grid(shape);
  const int step = tile_voxels / kLeafDim;  // bricks per tile edge
  const std::array<int, 3> bricks{grid.nbx, grid.nby, grid.nbz};
  std::array<int, 3> tiles{};
  for (int a = 0; a < 3; ++a) tiles[a] = (bricks[a] + step - 1) / step;
  const int total = tiles[0] * tiles[1] * tiles[2];
  int done = 0;
  for (int tz = 0; tz < tiles[2]; ++tz) {
    for (int ty = 0; ty < tiles[1]; ++ty) {
      for (int tx = 0; tx < tiles[0]; ++tx) {
        const std::array<int, 3> t{tx, ty, tz};
        BrickRange core;
        VoxelBox box;  // the core's voxels and the band around them, in the stack
        for (int a = 0; a < 3; ++a) {
          core.lo[a] = t[a] * step;
          core.hi[a] = std::min(bricks[a], core.lo[a] + step);
          box.lo[a] = std::max(0, core.lo[a] * kLeafDim - options.band_voxels);
          box.hi[a] = std::min(shape[a], core.hi[a] * kLeafDim + options.band_voxels);
        }
        Volume part;
        part.nx = box.hi[0] - box.lo[0];
        part.ny = box.hi[1] - box.lo[1];
        part.nz = box.hi[2] - box.lo[2];
        part.voxels.resize(part.size());
        source.read(box, part.voxels.data());
        (void)apply_normalization(part.voxels, normalization);
        build_tile(DenseBlock{part, box.lo}, shape, core, options, *impl);
        if (take_background) {
          SparseGrid(impl).visit_active_leaves(SparseGridPart::kBackground, take_background);
          impl->background->clear();
        }
        if (on_tile) on_tile(++done, total);
      }
    }
  }
  record_meta(*impl, shape, source.spacing, aspect, normalization, source.source, options);
  return SparseGrid(std::move(impl));
}

namespace {

openvdb::Vec3d to_vdb(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }
openvdb::Vec3d to_vdb(const std::array<double, 3>& v) { return {v[0], v[1], v[2]}; }

void put_meta(FloatGrid& g, const SparseGridMeta& m) {
  g.insertMeta("hisnegs_format_version", openvdb::Int32Metadata(1));
  g.insertMeta("volume_shape_xyz",
               openvdb::Vec3IMetadata(openvdb::Vec3i(m.shape_xyz[0], m.shape_xyz[1], m.shape_xyz[2])));
  g.insertMeta("spacing_um", openvdb::Vec3DMetadata(to_vdb(m.spacing_um)));
  g.insertMeta("aspect", openvdb::Vec3DMetadata(to_vdb(m.aspect)));
  g.insertMeta("normalization", openvdb::StringMetadata(std::string(to_string(m.normalization.method))));
  g.insertMeta("normalization_raw_lo", openvdb::DoubleMetadata(m.normalization.raw_lo));
  g.insertMeta("normalization_raw_hi", openvdb::DoubleMetadata(m.normalization.raw_hi));
  g.insertMeta("source", openvdb::StringMetadata(m.source));
  g.insertMeta("threshold", openvdb::DoubleMetadata(m.options.threshold));
  g.insertMeta("band_voxels", openvdb::Int32Metadata(m.options.band_voxels));
  g.insertMeta("background_fraction", openvdb::DoubleMetadata(m.options.background_fraction));
  g.insertMeta("background_seed", openvdb::Int64Metadata(static_cast<openvdb::Int64>(m.options.seed)));
}

template <class MetaT>
auto get_meta(const FloatGrid& g, const std::filesystem::path& path, const std::string& key) {
  const auto m = g.getMetadata<MetaT>(key);
  if (!m) fail_input(path, "grid '" + g.getName() + "' lacks metadata '" + key + "' (not written by hisnegs?)");
  return m->value();
}

NormalizationMethod parse_method(const std::filesystem::path& path, const std::string& s) {
  for (auto m : {NormalizationMethod::kNone, NormalizationMethod::kMinMax, NormalizationMethod::kPercentile}) {
    if (to_string(m) == s) return m;
  }
  fail_input(path, "metadata 'normalization' is '" + s + "'; expected none|minmax|percentile");
}

}  // namespace

void write_vdb(const std::filesystem::path& path, const SparseGrid& grid) {
  ensure_openvdb_initialized();
  const auto& impl = grid.impl();
  put_meta(*impl.volume, impl.meta);
  openvdb::GridPtrVec grids{impl.volume};
  if (impl.background->activeVoxelCount() > 0) grids.push_back(impl.background);
  write_vdb_file(path, grids);
}

SparseGrid read_vdb(const std::filesystem::path& path) {
  require_regular_file(path);
  ensure_openvdb_initialized();
  auto impl = std::make_shared<SparseGrid::Impl>();
  const VdbFileCheck check = check_vdb_structure(path);
  if (!find_grid(check, "volume")) fail_input(path, "has no grid named 'volume'");
  // Only a float grid's values are read: OpenVDB reads any other type in full,
  // sizes it states included, before gridPtrCast could refuse it.
  for (const char* name : {"volume", "background"}) {
    const VdbGridCheck* g = find_grid(check, name);
    if (g && (g->grid_type != "Tree_float_5_4_3" || !values_checked(check, name)))
      fail_input(path, "grid '" + std::string(name) + "' is " + printable(g->grid_type, 64) + ", not a float grid");
  }
  VdbReadGuard guard(path);
  try {
    guard.run([&] {
      openvdb::io::File file(path.string());
      file.open(false);
      impl->volume = openvdb::gridPtrCast<FloatGrid>(file.readGrid("volume"));
      if (!impl->volume) fail_input(path, "grid 'volume' is not a float grid");
      if (find_grid(check, "background"))
        impl->background = openvdb::gridPtrCast<FloatGrid>(file.readGrid("background"));
      file.close();
    });
  } catch (const openvdb::Exception& e) {
    fail_input(path, "not a readable OpenVDB file: " + printable(e.what()));  // OpenVDB messages can span lines
  } catch (const std::bad_alloc&) {
    fail_input(path, "damaged: reading it would take more than " + gib_text(guard.cap_bytes()) +
                         " of memory (64x the file, at least 1 GiB)");
  }
  if (!impl->background) {
    impl->background = FloatGrid::create(0.0f);
    impl->background->setTransform(impl->volume->transform().copy());
  }
  const FloatGrid& g = *impl->volume;
  auto& m = impl->meta;
  const auto shape = get_meta<openvdb::Vec3IMetadata>(g, path, "volume_shape_xyz");
  const auto spacing = get_meta<openvdb::Vec3DMetadata>(g, path, "spacing_um");
  const auto aspect = get_meta<openvdb::Vec3DMetadata>(g, path, "aspect");
  m.shape_xyz = {shape.x(), shape.y(), shape.z()};
  if (shape.x() <= 0 || shape.y() <= 0 || shape.z() <= 0)
    fail_input(path, "metadata 'volume_shape_xyz' is not positive");
  m.spacing_um = {spacing.x(), spacing.y(), spacing.z()};
  m.aspect = Eigen::Vector3d(aspect.x(), aspect.y(), aspect.z());
  m.normalization.method = parse_method(path, get_meta<openvdb::StringMetadata>(g, path, "normalization"));
  m.normalization.raw_lo = get_meta<openvdb::DoubleMetadata>(g, path, "normalization_raw_lo");
  m.normalization.raw_hi = get_meta<openvdb::DoubleMetadata>(g, path, "normalization_raw_hi");
  m.source = get_meta<openvdb::StringMetadata>(g, path, "source");
  m.options.threshold = get_meta<openvdb::DoubleMetadata>(g, path, "threshold");
  m.options.band_voxels = get_meta<openvdb::Int32Metadata>(g, path, "band_voxels");
  m.options.background_fraction = get_meta<openvdb::DoubleMetadata>(g, path, "background_fraction");
  m.options.seed = static_cast<std::uint64_t>(get_meta<openvdb::Int64Metadata>(g, path, "background_seed"));
  return SparseGrid(std::move(impl));
}

std::vector<VdbGridSummary> inspect_vdb(const std::filesystem::path& path) {
  require_regular_file(path);
  ensure_openvdb_initialized();
  std::vector<VdbGridSummary> out;
  const VdbFileCheck check = check_vdb_structure(path);
  VdbReadGuard guard(path);
  try {
    guard.run([&] {
      openvdb::io::File file(path.string());
      file.open(false);
      for (auto it = file.beginName(); it != file.endName(); ++it) {
        VdbGridSummary s;
        s.values_read = values_checked(check, *it);
        const openvdb::GridBase::Ptr grid = s.values_read ? file.readGrid(*it) : file.readGridMetadata(*it);
        s.name = grid->getName();
        s.value_type = grid->valueType();
        s.grid_class = openvdb::GridBase::gridClassToString(grid->getGridClass());
        const openvdb::Vec3d vs = grid->voxelSize();
        s.voxel_size = {vs.x(), vs.y(), vs.z()};
        if (s.values_read) {
          s.active_voxels = static_cast<std::int64_t>(grid->activeVoxelCount());
          s.memory_bytes = static_cast<std::int64_t>(grid->memUsage());
          const openvdb::CoordBBox bbox = grid->evalActiveVoxelBoundingBox();
          s.bbox_min = {bbox.min().x(), bbox.min().y(), bbox.min().z()};
          s.bbox_max = {bbox.max().x(), bbox.max().y(), bbox.max().z()};
          s.leaf_count = static_cast<std::int64_t>(grid->baseTreePtr()->leafCount());
        } else {
          // What the writer recorded (io::File writes these statistics by default).
          if (const auto n = grid->getMetadata<openvdb::Int64Metadata>(openvdb::GridBase::META_FILE_VOXEL_COUNT))
            s.active_voxels = std::max<std::int64_t>(n->value(), -1);
          if (const auto n = grid->getMetadata<openvdb::Int64Metadata>(openvdb::GridBase::META_FILE_MEM_BYTES))
            s.memory_bytes = std::max<std::int64_t>(n->value(), -1);
          const auto lo = grid->getMetadata<openvdb::Vec3IMetadata>(openvdb::GridBase::META_FILE_BBOX_MIN);
          const auto hi = grid->getMetadata<openvdb::Vec3IMetadata>(openvdb::GridBase::META_FILE_BBOX_MAX);
          if (lo && hi) {
            s.bbox_min = {lo->value().x(), lo->value().y(), lo->value().z()};
            s.bbox_max = {hi->value().x(), hi->value().y(), hi->value().z()};
          }
          if (const VdbGridCheck* g = find_grid(check, *it); g && g->depth != VdbGridCheck::Depth::kHeader)
            s.leaf_count = g->leaves;
        }
        for (auto m = grid->beginMeta(); m != grid->endMeta(); ++m) s.metadata[m->first] = m->second->str();
        out.push_back(std::move(s));
      }
      file.close();
    });
  } catch (const openvdb::Exception& e) {
    fail_input(path, "not a readable OpenVDB file: " + printable(e.what()));  // OpenVDB messages can span lines
  } catch (const std::bad_alloc&) {
    fail_input(path, "damaged: reading it would take more than " + gib_text(guard.cap_bytes()) +
                         " of memory (64x the file, at least 1 GiB)");
  }
  return out;
}

}  // namespace hisnegs::io
