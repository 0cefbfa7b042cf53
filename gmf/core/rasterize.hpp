// SPDX-License-Identifier: Apache-2.0
// The one 3D rasterizer of a mixture: f(x), the sum (report Eq. 1) or the softmax
// (f_β) of the terms a_k exp(-½ m_k(x)), at the voxel centres of a lattice, evaluated per 8³ block of voxels that some
// Gaussian's support reaches (so work and memory follow the supports, never their
// bounding box), each voxel summing its Gaussians in mixture order (values do not
// depend on the thread count). The dense volume, the fit's 3D PSNR, `export volume`
// and `export vdb` all rasterize through it. No OpenVDB here.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// The voxels a mixture is rasterized on: voxel (i, j, k) (column, row, page) has its
// centre at origin_world + voxel_size_world ⊙ (i, j, k), so integer indices are
// voxel centres, as in io::WorldFrame and in OpenVDB's index space. Optionally
// limited to an index box: the fit saw only the stack, so outside its box f is
// unconstrained (escaped Gaussians may spread there) and is left out.
struct VoxelLattice {
  struct IndexBox {
    Eigen::Vector3i min{0, 0, 0}, max{0, 0, 0};  // inclusive
  };
  Eigen::Vector3d voxel_size_world{1.0, 1.0, 1.0};  // world units per voxel along x, y, z, each finite > 0
  Eigen::Vector3d origin_world{0.0, 0.0, 0.0};      // centre of voxel (0, 0, 0), world units
  std::optional<IndexBox> clip;                     // voxels outside stay inactive; none = unbounded

  // The voxels of the stack `frame` describes (CONVENTIONS "World space"): voxel
  // (i, j, k) of the lattice is voxel (i, j, k) of the stack, clipped to 0..N-1.
  [[nodiscard]] static VoxelLattice of(const io::WorldFrame& frame);
  // Cubic voxels of edge `voxel_size_world` with a voxel centre at the world origin,
  // unbounded.
  [[nodiscard]] static VoxelLattice aligned(double voxel_size_world);
  // This lattice clipped to the voxels whose centres lie in the world box
  // [-aspect, aspect] (a stack's box, CONVENTIONS "World space").
  [[nodiscard]] VoxelLattice clipped_to_box(const Eigen::Vector3d& aspect) const;
  // Throws io::InputError("voxel size V: ...") for a non-finite or non-positive size.
  void validate() const;
};

// Which terms a voxel's value combines and how: Gaussian k counts at x where
// m_k(x) <= cutoff (δ, the renderer's support; infinity for none) and
// a_k exp(-m_k/2) >= tail (0 for none); the counted terms are summed or combined by
// the softmax at beta (gmf/core/aggregation.hpp).
struct RasterizeOptions {
  double cutoff = std::numeric_limits<double>::infinity();
  double tail = 0.0;
  Aggregation aggregation = Aggregation::kSum;
  double beta = 1.0;
  // The options that evaluate `model`'s f (its cutoff, aggregation and β).
  [[nodiscard]] static RasterizeOptions of(const MixtureModel& model) {
    return {model.cutoff, 0.0, model.aggregation, model.beta};
  }
  // The options an export evaluates `model`'s own f with, each term down to `tail`:
  // the function that was fitted, each term counted only inside the model's support
  // δ, as the fit and the renderer count it (a sum's tails beyond δ add up to ~2e-3
  // where Gaussians crowd; a softmax's far tails, though ~0, would take softmax weight
  // and pull f down wherever the signal is dim). `untruncated_sum`: a sum counts
  // every term everywhere instead (report Eq. 1 as written; not what was fitted).
  [[nodiscard]] static RasterizeOptions exported(const MixtureModel& model, double tail,
                                                 bool untruncated_sum = false) {
    RasterizeOptions o = of(model);
    if (model.aggregation == Aggregation::kSum && untruncated_sum) o.cutoff = std::numeric_limits<double>::infinity();
    o.tail = tail;
    return o;
  }
};

// Blocks are 8³ voxels (an OpenVDB leaf), aligned to multiples of 8 in index space.
inline constexpr int kRasterBlockLog2 = 3;
inline constexpr int kRasterBlockDim = 1 << kRasterBlockLog2;
inline constexpr int kRasterBlockVoxels = kRasterBlockDim * kRasterBlockDim * kRasterBlockDim;
// Voxel indices must stay within ±kRasterMaxIndex along each axis.
inline constexpr double kRasterMaxIndex = double(1 << 23) - kRasterBlockDim;

// A block's values, voxel (x, y, z) − origin at [(x · 8 + y) · 8 + z] (z fastest,
// OpenVDB's leaf order).
using BlockValues = std::array<double, kRasterBlockVoxels>;
[[nodiscard]] constexpr int block_offset(int x, int y, int z) {
  return (x << (2 * kRasterBlockLog2)) | (y << kRasterBlockLog2) | z;
}

// The blocks of a lattice that a mixture's supports reach, and their evaluation.
// Build once, then evaluate blocks in any order and from any thread.
class BlockRasterizer {
 public:
  // Throws io::InputError naming `model` when a support reaches past
  // ±kRasterMaxIndex (unclipped lattices of tiny voxels) or the (block, Gaussian)
  // bookkeeping would take more than half the allocation limit
  // (io::allocation_limit_bytes), and for an invalid lattice.
  BlockRasterizer(const GaussianMixture& mixture, const VoxelLattice& lattice, const RasterizeOptions& options,
                  const std::string& model);
  ~BlockRasterizer();
  BlockRasterizer(const BlockRasterizer&) = delete;
  BlockRasterizer& operator=(const BlockRasterizer&) = delete;

  [[nodiscard]] std::size_t blocks() const;
  // Index of block b's first voxel (multiples of 8).
  [[nodiscard]] Eigen::Vector3i block_origin(std::size_t b) const;
  // f at block b's voxel centres (0 outside every counted support and outside the clip).
  void evaluate(std::size_t b, BlockValues& out) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// f at every voxel centre of `frame` (float32, x fastest like io::Volume).
// TBB-parallel over blocks; deterministic. Memory: 4 bytes per voxel of the frame.
[[nodiscard]] std::vector<float> rasterize_mixture(const GaussianMixture& mixture, const io::WorldFrame& frame,
                                                   const RasterizeOptions& options);

// psnr(rasterize_mixture(mixture, frame, options), reference) without holding the
// rasterized volume: the squared error is Σ V² over every voxel plus, block by
// block, Σ (f − V)² − V² where the supports reach (f rounded to float as
// rasterize_mixture stores it). `reference` has the frame's voxel count.
// Deterministic; memory: one double per rasterized block.
[[nodiscard]] double mixture_psnr(const GaussianMixture& mixture, const io::WorldFrame& frame,
                                  const RasterizeOptions& options, std::span<const float> reference);

}  // namespace hisnegs::gmf
