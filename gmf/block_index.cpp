// SPDX-License-Identifier: Apache-2.0
// build_block_index: per-Gaussian support boxes -> per-block counts -> CSR, filled and sorted per block.
#include "gmf/block_index.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {

BlockIndex build_block_index(const GaussianMixture& mixture, const SampleSet& samples, const io::WorldFrame& frame,
                             double cutoff, double scale_pad, double pad_world) {
  return build_block_index(mixture, samples, frame, cutoff, scale_pad, Eigen::Vector3d::Constant(pad_world));
}

namespace {

// A dense map from leaf (8^3) coordinates to the sample blocks inside (several
// blocks per leaf, and a foreground and a background block may coincide), as CSR.
// The leaves span the stack and any samples outside it (negative origins).
class LeafMap {
 public:
  LeafMap(const SampleSet& samples, const io::WorldFrame& frame) : samples_(samples) {
    const Eigen::Vector3i& n = frame.shape();
    int hi_leaf[3] = {(n.x() + 7) / 8 - 1, (n.y() + 7) / 8 - 1, (n.z() + 7) / 8 - 1};
    for (const auto& o : samples.block_origin) {
      for (int a = 0; a < 3; ++a) {
        lo_leaf_[a] = std::min(lo_leaf_[a], leaf(o[a]));
        hi_leaf[a] = std::max(hi_leaf[a], leaf(o[a]));
      }
    }
    for (int a = 0; a < 3; ++a) nb_[a] = hi_leaf[a] - lo_leaf_[a] + 1;
    const std::size_t cells = static_cast<std::size_t>(nb_[0]) * nb_[1] * nb_[2];
    cell_begin_.assign(cells + 1, 0);
    cell_blocks_.resize(samples.blocks());
    for (const auto& o : samples.block_origin) ++cell_begin_[cell_of(o) + 1];
    for (std::size_t c = 0; c < cells; ++c) cell_begin_[c + 1] += cell_begin_[c];
    std::vector<std::uint32_t> fill(cell_begin_.begin(), cell_begin_.end() - 1);
    for (std::size_t b = 0; b < samples.blocks(); ++b) {
      cell_blocks_[fill[cell_of(samples.block_origin[b])]++] = static_cast<std::uint32_t>(b);
    }
  }

  // visit(b) for every block with a voxel centre in the index box [lo, hi].
  template <class Visit>
  void for_each_block_in(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, Visit&& visit) const {
    // Leaf l holds voxel centres 8l .. 8l + 7: overlap iff hi >= 8l and lo <= 8l + 7
    // (b0, b1: leaves relative to lo_leaf, clamped to the map).
    int b0[3], b1[3];
    for (int a = 0; a < 3; ++a) {
      const double first = std::clamp(std::ceil((lo[a] - 7.0) / 8.0) - lo_leaf_[a], 0.0, double(nb_[a]));
      const double last = std::clamp(std::floor(hi[a] / 8.0) - lo_leaf_[a], -1.0, double(nb_[a] - 1));
      b0[a] = static_cast<int>(first);
      b1[a] = static_cast<int>(last);
      if (b0[a] > b1[a]) return;
    }
    for (int bz = b0[2]; bz <= b1[2]; ++bz)
      for (int by = b0[1]; by <= b1[1]; ++by)
        for (int bx = b0[0]; bx <= b1[0]; ++bx) {
          const std::size_t c = (static_cast<std::size_t>(bz) * nb_[1] + by) * nb_[0] + bx;
          for (std::uint32_t i = cell_begin_[c]; i < cell_begin_[c + 1]; ++i) {
            // The block's voxel centres: origin .. origin + block - 1 per axis.
            const auto& o = samples_.block_origin[cell_blocks_[i]];
            bool overlap = true;
            for (int a = 0; a < 3; ++a) overlap = overlap && hi[a] >= o[a] && lo[a] <= o[a] + samples_.block - 1;
            if (overlap) visit(cell_blocks_[i]);
          }
        }
  }

 private:
  static int leaf(int v) { return floor_div(v, 8); }
  [[nodiscard]] std::size_t cell_of(const std::array<int, 3>& o) const {
    return (static_cast<std::size_t>(leaf(o[2]) - lo_leaf_[2]) * nb_[1] + (leaf(o[1]) - lo_leaf_[1])) * nb_[0] +
           (leaf(o[0]) - lo_leaf_[0]);
  }
  const SampleSet& samples_;
  int lo_leaf_[3] = {0, 0, 0}, nb_[3] = {0, 0, 0};
  std::vector<std::uint32_t> cell_begin_, cell_blocks_;
};

// The CSR of blocks → Gaussians from for_each_block_of(k, visit), which visits
// each block Gaussian k reaches. Two passes (count, then fill) straight into the
// CSR arrays: a list of (block, Gaussian) pairs to sort needed 4-6 times the
// index's memory at its peak, on a large stack more than the volume itself. Each
// block's list is sorted at the end.
template <class ForEach>
BlockIndex fill_index(std::size_t gaussians, std::size_t blocks, const ForEach& for_each_block_of) {
  BlockIndex index;
  std::vector<std::atomic<std::uint32_t>> count(blocks);
  for (auto& c : count) c.store(0, std::memory_order_relaxed);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, gaussians, 256), [&](const auto& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      for_each_block_of(k, [&](std::uint32_t b) { count[b].fetch_add(1, std::memory_order_relaxed); });
    }
  });
  index.begin.assign(blocks + 1, 0);
  for (std::size_t b = 0; b < blocks; ++b) {
    index.begin[b + 1] = index.begin[b] + count[b].load(std::memory_order_relaxed);
    count[b].store(index.begin[b], std::memory_order_relaxed);  // now the next free slot
  }
  index.gaussians.resize(index.begin[blocks]);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, gaussians, 256), [&](const auto& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      for_each_block_of(k, [&](std::uint32_t b) {
        index.gaussians[count[b].fetch_add(1, std::memory_order_relaxed)] = static_cast<std::uint32_t>(k);
      });
    }
  });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 1024), [&](const auto& r) {
    for (std::size_t b = r.begin(); b != r.end(); ++b) {
      std::sort(index.gaussians.begin() + index.begin[b], index.gaussians.begin() + index.begin[b + 1]);
    }
  });
  return index;
}

}  // namespace

BlockIndex build_block_index(const GaussianMixture& mixture, const SampleSet& samples, const io::WorldFrame& frame,
                             double cutoff, double scale_pad, const Eigen::Vector3d& pad_world) {
  const LeafMap leaves(samples, frame);
  // Every block Gaussian k's padded support box overlaps, in no particular order.
  const auto for_each_block_of = [&](std::size_t k, auto&& visit) {
    const GaussianFrame<double> f = frame_of(mixture[k]);
    const double* mean = f.mean;
    double half[3];
    support_half_extents(f, cutoff, half);
    for (int a = 0; a < 3; ++a) half[a] = half[a] * scale_pad + pad_world[a];
    const Eigen::Vector3d lo =
        frame.index_from_world(Eigen::Vector3d(mean[0] - half[0], mean[1] - half[1], mean[2] - half[2]));
    const Eigen::Vector3d hi =
        frame.index_from_world(Eigen::Vector3d(mean[0] + half[0], mean[1] + half[1], mean[2] + half[2]));
    leaves.for_each_block_in(lo, hi, visit);
  };
  return fill_index(mixture.size(), samples.blocks(), for_each_block_of);
}

double unreached_loss(const SampleSet& samples, const BlockIndex& index) {
  double loss = 0;
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    if (!index.of(b).empty()) continue;
    for (std::uint32_t s = samples.block_begin[b]; s < samples.block_begin[b + 1]; ++s) {
      loss += 0.5 * std::pow(samples.weight[s] * samples.value[s], 2);
    }
  }
  return loss;
}

}  // namespace hisnegs::gmf
