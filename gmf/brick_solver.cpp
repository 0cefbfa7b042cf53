// SPDX-License-Identifier: Apache-2.0
// partition_into_bricks (adaptive bricks, greedy colouring) and sweep_bricks (per
// colour, per brick: fixed terms, a small Ceres problem, exact LM, write back).
#include "gmf/brick_solver.hpp"

#include <ceres/ceres.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <tuple>

#include "gmf/detail/block_cost.hpp"
#include "gmf/detail/candidates.hpp"
#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {
namespace {

// A brick: its edge is brick_voxels >> level voxels, (x, y, z) in units of that edge.
struct BrickKey {
  int level, x, y, z;
  bool operator<(const BrickKey& o) const { return std::tie(level, z, y, x) < std::tie(o.level, o.z, o.y, o.x); }
};

BrickKey key_at(const Eigen::Vector3d& index, int edge, int level) {
  const auto cell = [edge](double v) {
    // Clamped so that Gaussians far outside the stack still get an int key.
    return static_cast<int>(std::floor(std::clamp(v, -1e8, 1e8) / edge));
  };
  return {level, cell(index.x()), cell(index.y()), cell(index.z())};
}

// Greedy colouring: brick by brick, the smallest colour none of the bricks that
// share one of its sample blocks has yet.
std::vector<std::vector<std::uint32_t>> colour_bricks(const BrickPartition& p, const BlockIndex& index) {
  const std::size_t bricks = p.gaussians.size();
  std::vector<int> colour(bricks, -1);
  std::vector<std::uint32_t> seen_at;  // per colour: the last brick that saw it taken (a mark without clearing)
  std::vector<std::vector<std::uint32_t>> colours;
  for (std::uint32_t b = 0; b < bricks; ++b) {
    for (std::uint32_t block : p.blocks[b]) {
      for (std::uint32_t g : index.of(block)) {
        const int c = colour[p.brick_of[g]];
        if (c >= 0) seen_at[static_cast<std::size_t>(c)] = b + 1;
      }
    }
    int c = 0;
    while (c < static_cast<int>(colours.size()) && seen_at[static_cast<std::size_t>(c)] == b + 1) ++c;
    if (c == static_cast<int>(colours.size())) {
      colours.emplace_back();
      seen_at.push_back(0);
    }
    colour[b] = c;
    colours[static_cast<std::size_t>(c)].push_back(b);
  }
  return colours;
}

// The terms of the Gaussians of `index.of(block)` that are not in brick `b`, at
// every sample of the block. `frames` holds every Gaussian's frame as of the start
// of the colour (the bricks of one colour never reach each other's blocks, so the
// Gaussians b sees as fixed do not change while the colour is solved).
void fixed_terms_of_block(const SampleSet& samples, std::uint32_t block, const BlockIndex& index,
                          const BrickPartition& partition, std::uint32_t b,
                          std::span<const GaussianFrame<double>> frames, const MixtureModel& model,
                          std::span<PointTerms<double>> out) {
  thread_local std::vector<const GaussianFrame<double>*> fixed;
  fixed.clear();
  for (std::uint32_t g : index.of(block)) {
    if (partition.brick_of[g] != b) fixed.push_back(&frames[g]);
  }
  const std::uint32_t first = samples.block_begin[block];
  for (std::size_t j = 0; j < out.size(); ++j) {
    const double x[3] = {samples.x[first + j], samples.y[first + j], samples.z[first + j]};
    PointTerms<double> t = no_terms<double>();
    for (const GaussianFrame<double>* fp : fixed) {
      const GaussianFrame<double>& f = *fp;
      double z[3];
      const double m = mahalanobis(f, x, z);
      if (m > model.cutoff) continue;
      const double term = f.a * std::exp(-0.5 * m);
      add_term(t, term, model);
    }
    out[j] = t;
  }
}

// All of a brick's sample blocks as ONE residual block over all its Gaussians:
// Ceres then forms the normal equations of a small dense problem with one GEMM
// instead of walking hundreds of tiny blocks (its per-block bookkeeping cost more
// than the arithmetic). Block k's residuals are rows [row_[k], row_[k + 1]); its
// BlockCost writes them straight into the brick's Jacobian, whose row-major
// layout per Gaussian makes each block's rows one contiguous slice.
class BrickCost final : public ceres::CostFunction {
 public:
  struct Block {
    std::unique_ptr<detail::BlockCost> cost;
    std::vector<std::uint32_t> gaussians;  // local indices of the free Gaussians reaching it
  };
  BrickCost(std::vector<Block> blocks, std::size_t gaussians) : blocks_(std::move(blocks)), gaussians_(gaussians) {
    row_.push_back(0);
    for (const Block& b : blocks_) row_.push_back(row_.back() + b.cost->num_residuals());
    set_num_residuals(row_.back());
    mutable_parameter_block_sizes()->assign(gaussians_, kGaussianParamCount);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    thread_local std::vector<const double*> p;
    thread_local std::vector<double*> j;
    if (jacobians) {
      for (std::size_t g = 0; g < gaussians_; ++g) {
        if (jacobians[g]) std::fill_n(jacobians[g], static_cast<std::size_t>(row_.back()) * kGaussianParamCount, 0.0);
      }
    }
    for (std::size_t k = 0; k < blocks_.size(); ++k) {
      const Block& b = blocks_[k];
      p.clear();
      j.clear();
      for (std::uint32_t g : b.gaussians) {
        p.push_back(parameters[g]);
        if (jacobians) {
          j.push_back(jacobians[g] ? jacobians[g] + static_cast<std::size_t>(row_[k]) * kGaussianParamCount : nullptr);
        }
      }
      if (!b.cost->Evaluate(p.data(), residuals + row_[k], jacobians ? j.data() : nullptr)) return false;
    }
    return true;
  }

 private:
  std::vector<Block> blocks_;
  std::size_t gaussians_;
  std::vector<int> row_;
};

std::size_t samples_in(const SampleSet& samples, const std::vector<std::uint32_t>& blocks) {
  std::size_t total = 0;
  for (std::uint32_t block : blocks) total += samples.block_begin[block + 1] - samples.block_begin[block];
  return total;
}

// Exact LM for one brick: sparse normal equations where Ceres has them, one thread.
ceres::Solver::Options brick_solver_options(const BrickSweepOptions& options, double seconds_left) {
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  // Sparse normal equations (SuiteSparse, or Eigen's sparse Cholesky) where Ceres
  // has one: they are formed chunk by chunk. Without one, dense.
  static const ceres::SparseLinearAlgebraLibraryType sparse_library =
      ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::SUITE_SPARSE) ? ceres::SUITE_SPARSE : ceres::EIGEN_SPARSE;
  if (options.sparse && ceres::IsSparseLinearAlgebraLibraryTypeAvailable(sparse_library)) {
    so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    so.sparse_linear_algebra_library_type = sparse_library;
  } else {
    so.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  }
  so.max_num_iterations = options.iterations;
  so.max_solver_time_in_seconds = seconds_left;
  // Ceres starts at radius 1e4 (μ 1e-4: nearly plain Gauss–Newton); on the softmax
  // the first steps are then rejected until the radius has shrunk, which spent
  // most of a brick's few iterations. op1, one sweep from the grid init: loss
  // 2009 → 1792 at 1e4, → 788 at 1, → 1330 at 0.01 (docs/benchmarks.md).
  so.initial_trust_region_radius = 1.0;
  so.num_threads = 1;  // bricks run in parallel instead; one thread keeps each solve deterministic
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  return so;
}

// Exact LM on brick b's Gaussians; returns its iterations, or -1 when skipped.
int solve_brick(std::uint32_t b, const SampleSet& samples, const BlockIndex& index, const BrickPartition& partition,
                std::span<ParamsD> params, std::span<const GaussianFrame<double>> frames,
                std::span<const std::array<double, 4>> balls, std::span<const double> lower,
                std::span<const double> upper, const BrickSweepOptions& options, double seconds_left) {
  static detail::GaussianManifold manifold;  // stateless: shared by every thread
  const std::vector<std::uint32_t>& ids = partition.gaussians[b];
  const std::vector<std::uint32_t>& blocks = partition.blocks[b];
  if (!(seconds_left > 0)) return -1;
  if (ids.empty() || blocks.empty()) return 0;  // reaches no sample: nothing to fit
  std::vector<ParamsD> local(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) local[i] = params[ids[i]];
  const auto local_of = [&](std::uint32_t g) {
    return static_cast<std::size_t>(std::lower_bound(ids.begin(), ids.end(), g) - ids.begin());
  };

  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  for (std::size_t i = 0; i < ids.size(); ++i) {
    const std::size_t at = static_cast<std::size_t>(ids[i]) * kGaussianParamCount;
    detail::add_gaussian_block(problem, local[i].data(), &manifold, &lower[at], &upper[at]);
  }
  // The fixed terms live as long as the problem (its costs keep spans into them).
  std::vector<PointTerms<double>> fixed(samples_in(samples, blocks));
  std::size_t offset = 0;
  // The brick's sample blocks, in order, grouped into chunks whose free Gaussians
  // (the union over the chunk's blocks) stay within options.chunk_gaussians: one
  // residual block per chunk, over only those Gaussians, so the normal equations
  // are formed block-sparse (a chunk's dense JᵀJ is at most chunk_gaussians²
  // parameter blocks) rather than as one rows × all-Gaussians GEMM.
  std::vector<BrickCost::Block> costs;
  std::vector<std::uint32_t> chunk;                    // local ids of the chunk's Gaussians, in first-seen order
  std::vector<std::int32_t> in_chunk(ids.size(), -1);  // local id -> its position in `chunk`, or -1
  const auto flush = [&] {
    if (costs.empty()) return;
    std::vector<double*> parameter_blocks;
    parameter_blocks.reserve(chunk.size());
    for (std::uint32_t l : chunk) parameter_blocks.push_back(local[l].data());
    problem.AddResidualBlock(new BrickCost(std::move(costs), chunk.size()), nullptr, parameter_blocks);
    for (std::uint32_t l : chunk) in_chunk[l] = -1;
    chunk.clear();
    costs.clear();
  };
  std::vector<std::uint32_t> mine;
  const double reach = std::sqrt(options.model.cutoff) + options.reach_margin;
  for (std::uint32_t block : blocks) {
    const std::size_t n = samples.block_begin[block + 1] - samples.block_begin[block];
    mine.clear();
    for (std::uint32_t g : index.of(block)) {
      if (partition.brick_of[g] != b) continue;
      if (detail::sqrt_mahalanobis_lower_bound(frames[g], balls[block]) > reach) continue;
      mine.push_back(static_cast<std::uint32_t>(local_of(g)));
    }
    if (mine.empty()) continue;  // none of the brick's Gaussians can reach it: its residuals are constant
    const std::span<PointTerms<double>> terms(fixed.data() + offset, n);
    offset += n;
    fixed_terms_of_block(samples, block, index, partition, b, frames, options.model, terms);
    std::size_t added = 0;
    for (std::uint32_t l : mine) added += in_chunk[l] < 0 ? 1 : 0;
    if (!chunk.empty() && chunk.size() + added > static_cast<std::size_t>(options.chunk_gaussians)) flush();
    BrickCost::Block c;
    for (std::uint32_t l : mine) {
      if (in_chunk[l] < 0) {
        in_chunk[l] = static_cast<std::int32_t>(chunk.size());
        chunk.push_back(l);
      }
      c.gaussians.push_back(static_cast<std::uint32_t>(in_chunk[l]));
    }
    c.cost = std::make_unique<detail::BlockCost>(samples, block, c.gaussians.size(), options.model, terms);
    costs.push_back(std::move(c));
  }
  flush();
  if (problem.NumResidualBlocks() == 0) return 0;  // no Gaussian of the brick reaches a sample now

  const ceres::Solver::Options so = brick_solver_options(options, seconds_left);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (summary.termination_type == ceres::FAILURE) return 0;  // e.g. a non-finite start: the brick keeps its values
  for (std::size_t i = 0; i < ids.size(); ++i) params[ids[i]] = local[i];
  return summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
}

}  // namespace

BrickPartition partition_into_bricks(std::span<const ParamsD> params, const BlockIndex& index,
                                     const io::WorldFrame& frame, int brick_voxels, int max_gaussians) {
  const std::size_t K = params.size();
  std::vector<Eigen::Vector3d> centre(K);
  for (std::size_t k = 0; k < K; ++k) {
    centre[k] = frame.index_from_world(Eigen::Vector3d(params[k][kMeanX], params[k][kMeanY], params[k][kMeanZ]));
  }
  std::vector<BrickKey> key(K);
  for (std::size_t k = 0; k < K; ++k) key[k] = key_at(centre[k], brick_voxels, 0);
  // Halve crowded bricks until none holds more than max_gaussians (or they are 2 voxels).
  for (int level = 0; (brick_voxels >> level) > 2; ++level) {
    std::map<BrickKey, int> count;
    for (const BrickKey& k : key) ++count[k];
    bool split = false;
    for (std::size_t k = 0; k < K; ++k) {
      if (key[k].level == level && count[key[k]] > max_gaussians) {
        key[k] = key_at(centre[k], brick_voxels >> (level + 1), level + 1);
        split = true;
      }
    }
    if (!split) break;
  }
  std::map<BrickKey, std::uint32_t> id;
  for (const BrickKey& k : key) id.emplace(k, 0);
  std::uint32_t next = 0;
  for (auto& [k, v] : id) v = next++;
  BrickPartition p;
  p.brick_of.resize(K);
  p.gaussians.resize(id.size());
  p.blocks.resize(id.size());
  for (std::size_t k = 0; k < K; ++k) {
    p.brick_of[k] = id[key[k]];
    p.gaussians[p.brick_of[k]].push_back(static_cast<std::uint32_t>(k));
  }
  for (std::size_t block = 0; block + 1 < index.begin.size(); ++block) {
    for (std::uint32_t g : index.of(block)) {
      std::vector<std::uint32_t>& list = p.blocks[p.brick_of[g]];
      if (list.empty() || list.back() != block) list.push_back(static_cast<std::uint32_t>(block));
    }
  }
  p.colours = colour_bricks(p, index);
  return p;
}

BrickSweepStats sweep_bricks(const SampleSet& samples, const BlockIndex& index, const BrickPartition& partition,
                             std::span<ParamsD> params, std::span<const double> lower, std::span<const double> upper,
                             const BrickSweepOptions& options) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto seconds_left = [&] {
    return options.seconds_left - std::chrono::duration<double>(Clock::now() - start).count();
  };
  BrickSweepStats stats;
  std::atomic<int> solved{0}, skipped{0};
  std::atomic<std::int64_t> iterations{0};
  // Every Gaussian's frame, kept current colour by colour: after a colour, only its
  // bricks' Gaussians have moved.
  std::vector<GaussianFrame<double>> frames(params.size());
  tbb::parallel_for(std::size_t{0}, params.size(),
                    [&](std::size_t g) { prepare_gaussian(params[g].data(), frames[g]); });
  // Every sample block's ball, once per sweep (a block is in the problems of
  // several bricks).
  std::vector<std::array<double, 4>> balls(samples.blocks());
  tbb::parallel_for(std::size_t{0}, balls.size(), [&](std::size_t block) {
    const std::uint32_t s0 = samples.block_begin[block], s1 = samples.block_begin[block + 1];
    if (s1 > s0) balls[block] = detail::sample_ball(samples, s0, s1);
  });
  for (const std::vector<std::uint32_t>& bricks : partition.colours) {
    tbb::parallel_for(std::size_t{0}, bricks.size(), [&](std::size_t i) {
      const int it = solve_brick(bricks[i], samples, index, partition, params, frames, balls, lower, upper, options,
                                 seconds_left());
      if (it < 0) {
        ++skipped;
      } else {
        ++solved;
        iterations += it;
      }
    });
    tbb::parallel_for(std::size_t{0}, bricks.size(), [&](std::size_t i) {
      for (std::uint32_t g : partition.gaussians[bricks[i]]) prepare_gaussian(params[g].data(), frames[g]);
    });
  }
  stats.bricks_solved = solved;
  stats.bricks_skipped = skipped;
  stats.iterations = iterations;
  return stats;
}

}  // namespace hisnegs::gmf
