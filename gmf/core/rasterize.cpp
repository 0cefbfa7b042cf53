// SPDX-License-Identifier: Apache-2.0
// BlockRasterizer: per-Gaussian supports -> sorted (block, Gaussian) pairs -> f per
// block in mixture order; rasterize_mixture on it; VoxelLattice.
#include "gmf/core/rasterize.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <string>

#include "gmf/core/gaussian_math.hpp"
#include "gmf/core/psnr.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::gmf {
namespace {

// Block coordinates (voxel index >> 3) packed in 21 bits per axis: indices within
// ±kRasterMaxIndex fit.
constexpr int kKeyBits = 21;
static_assert(kRasterMaxIndex < double(1 << (kKeyBits - 1 + kRasterBlockLog2)));

std::uint64_t block_key(int bx, int by, int bz) {
  constexpr int kBias = 1 << (kKeyBits - 1);
  const auto u = [](int v) { return static_cast<std::uint64_t>(static_cast<std::int64_t>(v) + kBias); };
  return (u(bz) << (2 * kKeyBits)) | (u(by) << kKeyBits) | u(bx);
}

Eigen::Vector3i origin_of_key(std::uint64_t key) {
  constexpr int kBias = 1 << (kKeyBits - 1);
  constexpr std::uint64_t kMask = (std::uint64_t{1} << kKeyBits) - 1;
  const auto v = [](std::uint64_t bits) { return (static_cast<int>(bits & kMask) - kBias) * kRasterBlockDim; };
  return {v(key), v(key >> kKeyBits), v(key >> (2 * kKeyBits))};
}

// One Gaussian's part: its frame, the Mahalanobis bound of the terms counted
// (min of the cutoff and 2 ln(a / tail)), and the voxel-index box holding them.
struct Support {
  GaussianFrame<double> f;
  double m_max = 0;
  std::array<int, 3> lo{1, 1, 1}, hi{0, 0, 0};  // empty unless lo <= hi on every axis
  [[nodiscard]] bool empty() const { return lo[0] > hi[0] || lo[1] > hi[1] || lo[2] > hi[2]; }
};

struct Pair {
  std::uint64_t block;
  std::uint32_t gaussian;
  bool operator<(const Pair& o) const { return block < o.block || (block == o.block && gaussian < o.gaussian); }
};

std::string size_text(const Eigen::Vector3d& v) {
  return v.x() == v.y() && v.y() == v.z()
             ? io::number_text(v.x())
             : io::number_text(v.x()) + "," + io::number_text(v.y()) + "," + io::number_text(v.z());
}

bool frame_is_finite(const GaussianFrame<double>& f) {
  bool finite = std::isfinite(f.a);
  for (int d = 0; d < 3; ++d) finite = finite && std::isfinite(f.mean[d]) && std::isfinite(f.scale[d]);
  for (const double r : f.R) finite = finite && std::isfinite(r);
  return finite;
}

// The index box of support `s` on the lattice; false when a bound passes the
// packable range.
bool place_support(Support& s, const VoxelLattice& lattice) {
  double half[3];
  support_half_extents(s.f, s.m_max, half);
  for (int d = 0; d < 3; ++d) {
    const double v = lattice.voxel_size_world[d], o = lattice.origin_world[d];
    double lo = std::ceil((s.f.mean[d] - half[d] - o) / v);
    double hi = std::floor((s.f.mean[d] + half[d] - o) / v);
    if (lattice.clip) {
      lo = std::max(lo, static_cast<double>(lattice.clip->min[d]));
      hi = std::min(hi, static_cast<double>(lattice.clip->max[d]));
    }
    if (hi < lo) return true;  // outside the clip box (or between two voxel centres): empty
    if (!(std::abs(lo) <= kRasterMaxIndex && std::abs(hi) <= kRasterMaxIndex)) return false;
    s.lo[d] = static_cast<int>(lo);
    s.hi[d] = static_cast<int>(hi);
  }
  return true;
}

}  // namespace

struct BlockRasterizer::Impl {
  VoxelLattice lattice;
  RasterizeOptions options;
  std::vector<Support> supports;
  std::vector<Pair> pairs;         // sorted: each block lists its Gaussians in mixture order
  std::vector<std::size_t> begin;  // block i holds pairs[begin[i] .. begin[i + 1])

  // Supports of all Gaussians; returns Σ_k blocks of box k.
  double build_supports(const GaussianMixture& mixture, const RasterizeOptions& options, const std::string& model);
  void build_pairs(std::int64_t pair_count);
};

double BlockRasterizer::Impl::build_supports(const GaussianMixture& mixture, const RasterizeOptions& options,
                                             const std::string& model) {
  supports.resize(mixture.size());
  std::atomic<bool> out_of_range{false};
  std::atomic<std::size_t> non_finite{mixture.size()};  // the first Gaussian with a NaN or Inf, if any
  tbb::combinable<double> total(0.0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mixture.size(), 1024), [&](const auto& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      Support& s = supports[k];
      s.f = frame_of(mixture[k]);
      if (!frame_is_finite(s.f)) {
        std::size_t first = non_finite.load();
        while (k < first && !non_finite.compare_exchange_weak(first, k)) {
        }
        s.lo = {1, 1, 1};
        s.hi = {0, 0, 0};
        continue;
      }
      s.m_max = options.cutoff;
      if (options.tail > 0.0) {
        if (!(s.f.a > options.tail)) continue;  // never reaches `tail` anywhere: left out entirely
        s.m_max = std::min(s.m_max, 2.0 * std::log(s.f.a / options.tail));
      }
      if (!place_support(s, lattice)) {
        out_of_range = true;
        s.lo = {1, 1, 1};
        s.hi = {0, 0, 0};
        continue;
      }
      if (s.empty()) continue;
      double blocks = 1.0;
      for (int d = 0; d < 3; ++d) blocks *= double((s.hi[d] >> kRasterBlockLog2) - (s.lo[d] >> kRasterBlockLog2) + 1);
      total.local() += blocks;
    }
  });
  if (non_finite.load() < mixture.size()) {
    io::fail_input(model, "Gaussian " + std::to_string(non_finite.load()) +
                              " has a non-finite parameter (NaN or Inf); nothing can be rasterized from it");
  }
  if (out_of_range) {
    io::fail_input(model, "at voxel size " + size_text(lattice.voxel_size_world) +
                              " the Gaussians reach past voxel index ±" + io::number_text(kRasterMaxIndex) +
                              "; use a larger voxel size");
  }
  return total.combine(std::plus<>());
}

void BlockRasterizer::Impl::build_pairs(std::int64_t pair_count) {
  pairs.reserve(static_cast<std::size_t>(pair_count));
  tbb::combinable<std::vector<Pair>> local;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, supports.size(), 256), [&](const auto& r) {
    auto& out = local.local();
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      const Support& s = supports[k];
      if (s.empty()) continue;
      for (int bz = s.lo[2] >> kRasterBlockLog2; bz <= s.hi[2] >> kRasterBlockLog2; ++bz)
        for (int by = s.lo[1] >> kRasterBlockLog2; by <= s.hi[1] >> kRasterBlockLog2; ++by)
          for (int bx = s.lo[0] >> kRasterBlockLog2; bx <= s.hi[0] >> kRasterBlockLog2; ++bx)
            out.push_back({block_key(bx, by, bz), static_cast<std::uint32_t>(k)});
    }
  });
  local.combine_each([&](std::vector<Pair>& v) {
    pairs.insert(pairs.end(), v.begin(), v.end());
    std::vector<Pair>().swap(v);
  });
  tbb::parallel_sort(pairs.begin(), pairs.end());
  for (std::size_t i = 0; i < pairs.size(); ++i) {
    if (i == 0 || pairs[i].block != pairs[i - 1].block) begin.push_back(i);
  }
  begin.push_back(pairs.size());
}

BlockRasterizer::BlockRasterizer(const GaussianMixture& mixture, const VoxelLattice& lattice,
                                 const RasterizeOptions& options, const std::string& model)
    : impl_(std::make_unique<Impl>()) {
  lattice.validate();
  impl_->lattice = lattice;
  impl_->options = options;
  const double total = impl_->build_supports(mixture, options, model);
  // Each candidate pair costs its 16 bytes plus, at worst, its own block slot. This
  // guards the bookkeeping, which scales with the supports; what a caller keeps per
  // block is its own output.
  const double need = total * (sizeof(Pair) + sizeof(void*));
  const double have = io::allocation_limit_bytes();
  if (need > 0.5 * have) {
    constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;
    io::fail_input(model, "at voxel size " + size_text(lattice.voxel_size_world) + " the Gaussians' supports reach " +
                              io::number_text(total) + " leaves of 8^3 voxels (" + io::number_text(need / kGiB) +
                              " GiB of bookkeeping alone, " + io::number_text(have / kGiB) +
                              " GiB available); use a larger voxel size");
  }
  impl_->build_pairs(static_cast<std::int64_t>(total));
}

BlockRasterizer::~BlockRasterizer() = default;

std::size_t BlockRasterizer::blocks() const { return impl_->begin.size() - 1; }

Eigen::Vector3i BlockRasterizer::block_origin(std::size_t b) const {
  return origin_of_key(impl_->pairs[impl_->begin[b]].block);
}

void BlockRasterizer::evaluate(std::size_t b, BlockValues& out) const {
  const Impl& d = *impl_;
  const Eigen::Vector3i origin = block_origin(b);
  const Eigen::Vector3d& vs = d.lattice.voxel_size_world;
  const Eigen::Vector3d& org = d.lattice.origin_world;
  const MixtureModel model{d.options.aggregation, d.options.beta, d.options.cutoff};
  std::array<PointTerms<double>, kRasterBlockVoxels> terms;
  terms.fill(no_terms<double>());
  for (std::size_t p = d.begin[b]; p < d.begin[b + 1]; ++p) {
    const Support& s = d.supports[d.pairs[p].gaussian];
    int lo[3], hi[3];
    bool overlap = true;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(s.lo[a], origin[a]);
      hi[a] = std::min(s.hi[a], origin[a] + kRasterBlockDim - 1);
      overlap = overlap && lo[a] <= hi[a];
    }
    if (!overlap) continue;
    for (int x = lo[0]; x <= hi[0]; ++x) {
      for (int y = lo[1]; y <= hi[1]; ++y) {
        for (int z = lo[2]; z <= hi[2]; ++z) {
          const double xw[3] = {org.x() + vs.x() * x, org.y() + vs.y() * y, org.z() + vs.z() * z};
          double local[3];
          const double m = mahalanobis(s.f, xw, local);
          if (!(m <= s.m_max)) continue;
          // = evaluate_gaussian(s.f, xw, nullptr), without computing m twice.
          const double term = s.f.a * std::exp(-0.5 * m);
          add_term(terms[static_cast<std::size_t>(block_offset(x - origin.x(), y - origin.y(), z - origin.z()))], term,
                   model);
        }
      }
    }
  }
  for (std::size_t i = 0; i < terms.size(); ++i) out[i] = terms_value(terms[i], model);
}

namespace {

// visit(b, i, f) for every voxel of every block of `raster` inside the frame's
// shape `n`: i the voxel's linear index (x fastest), f its value. TBB-parallel over
// blocks; each block is visited by one thread.
template <class Visit>
void for_each_rasterized_voxel(const BlockRasterizer& raster, const Eigen::Vector3i& n, Visit&& visit) {
  const std::size_t plane = static_cast<std::size_t>(n.x()) * n.y();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, raster.blocks(), 4), [&](const auto& r) {
    BlockValues values;
    for (std::size_t b = r.begin(); b != r.end(); ++b) {
      raster.evaluate(b, values);
      const Eigen::Vector3i o = raster.block_origin(b);
      const Eigen::Vector3i hi = (o + Eigen::Vector3i::Constant(kRasterBlockDim)).cwiseMin(n);
      for (int z = o.z(); z < hi.z(); ++z)
        for (int y = o.y(); y < hi.y(); ++y)
          for (int x = o.x(); x < hi.x(); ++x) {
            visit(b, plane * z + static_cast<std::size_t>(y) * n.x() + x,
                  values[block_offset(x - o.x(), y - o.y(), z - o.z())]);
          }
    }
  });
}

}  // namespace

std::vector<float> rasterize_mixture(const GaussianMixture& mixture, const io::WorldFrame& frame,
                                     const RasterizeOptions& options) {
  const Eigen::Vector3i& n = frame.shape();
  std::vector<float> out(static_cast<std::size_t>(n.x()) * n.y() * n.z(), 0.0f);
  const BlockRasterizer raster(mixture, VoxelLattice::of(frame), options, "mixture");
  for_each_rasterized_voxel(raster, n,
                            [&](std::size_t, std::size_t i, double f) { out[i] = static_cast<float>(f); });
  return out;
}

double mixture_psnr(const GaussianMixture& mixture, const io::WorldFrame& frame, const RasterizeOptions& options,
                    std::span<const float> reference) {
  const Eigen::Vector3i& n = frame.shape();
  const std::size_t plane = static_cast<std::size_t>(n.x()) * n.y();
  if (reference.size() != plane * static_cast<std::size_t>(n.z()) || reference.empty()) {
    throw std::invalid_argument("mixture_psnr: " + std::to_string(reference.size()) + " reference values for a " +
                                std::to_string(n.x()) + "x" + std::to_string(n.y()) + "x" + std::to_string(n.z()) +
                                " frame");
  }
  double se = sum_of_squares(reference);  // the squared error of f = 0
  const BlockRasterizer raster(mixture, VoxelLattice::of(frame), options, "mixture");
  std::vector<double> block_se(raster.blocks(), 0.0);  // Σ (f − V)² − V² per block
  for_each_rasterized_voxel(raster, n, [&](std::size_t b, std::size_t i, double f) {
    const double v = reference[i];
    const double d = static_cast<double>(static_cast<float>(f)) - v;
    block_se[b] += d * d - v * v;
  });
  for (double d : block_se) se += d;
  return psnr_from_mse(std::max(0.0, se) / static_cast<double>(reference.size()));
}

VoxelLattice VoxelLattice::of(const io::WorldFrame& frame) {
  VoxelLattice l;
  l.voxel_size_world = frame.voxel_size();
  l.origin_world = frame.world_from_index(Eigen::Vector3d::Zero());
  l.clip = IndexBox{Eigen::Vector3i::Zero(), frame.shape() - Eigen::Vector3i::Ones()};
  return l;
}

VoxelLattice VoxelLattice::aligned(double voxel_size_world) {
  VoxelLattice l;
  l.voxel_size_world = Eigen::Vector3d::Constant(voxel_size_world);
  l.origin_world = Eigen::Vector3d::Zero();
  return l;
}

VoxelLattice VoxelLattice::clipped_to_box(const Eigen::Vector3d& aspect) const {
  validate();
  VoxelLattice l = *this;
  IndexBox box;
  for (int d = 0; d < 3; ++d) {
    // Centres origin + v i inside [-a, a]; the index range check of the rasterizer
    // applies afterwards, so the bounds are only kept within int range here.
    const double lo = std::ceil((-aspect[d] - origin_world[d]) / voxel_size_world[d]);
    const double hi = std::floor((aspect[d] - origin_world[d]) / voxel_size_world[d]);
    box.min[d] = static_cast<int>(std::clamp(lo, -2.0 * kRasterMaxIndex, 2.0 * kRasterMaxIndex));
    box.max[d] = static_cast<int>(std::clamp(hi, -2.0 * kRasterMaxIndex, 2.0 * kRasterMaxIndex));
  }
  if (clip) {
    box.min = box.min.cwiseMax(clip->min);
    box.max = box.max.cwiseMin(clip->max);
  }
  l.clip = box;
  return l;
}

void VoxelLattice::validate() const {
  for (int d = 0; d < 3; ++d) {
    const double v = voxel_size_world[d];
    if (!std::isfinite(v) || !(v > 0.0)) {
      throw io::InputError("voxel size " + io::number_text(v) + ": must be a finite number > 0 (world units)");
    }
    if (!std::isfinite(origin_world[d])) throw io::InputError("lattice origin is not finite");
  }
  if (clip && (clip->min.array() > clip->max.array()).any()) {
    throw io::InputError("lattice clip box is empty: the voxel size exceeds the stack's box");
  }
}

}  // namespace hisnegs::gmf
