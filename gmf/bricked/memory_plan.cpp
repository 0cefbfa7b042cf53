// SPDX-License-Identifier: Apache-2.0
// largest_core, core_for_ranks and choose_fit_plan.
#include "gmf/bricked/memory_plan.hpp"

#include <algorithm>
#include <cmath>

#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::gmf {

double brick_max_scale(const io::WorldFrame& frame, const GmfOptions& gmf) {
  return gmf.stream_scale_voxels * frame.voxel_size().minCoeff();
}

namespace {

std::size_t region_voxels(const std::array<int, 3>& shape, int core, const std::array<int, 3>& halo) {
  std::size_t n = 1;
  for (int a = 0; a < 3; ++a) n *= static_cast<std::size_t>(std::min(shape[a], std::min(core, shape[a]) + 2 * halo[a]));
  return n;
}

}  // namespace

int largest_core(const std::array<int, 3>& shape, int smallest, double bytes, const std::function<double(int)>& need) {
  int core = *std::max_element(shape.begin(), shape.end());
  while (core > smallest && need(core) > bytes) core = std::max(smallest, (core * 3 / 4) / 16 * 16);
  return core;
}

FitPlanChoice choose_fit_plan(const std::array<int, 3>& shape, const io::WorldFrame& frame, const GmfOptions& gmf,
                              const FitMemoryModel& memory, int ranks) {
  FitPlanChoice c;
  const io::MemoryLimit limit = io::resolve_memory_limit(gmf.max_memory, "gmf.max_memory");
  c.max_memory = limit.bytes;
  c.memory_source = limit.source;
  const std::size_t voxels = static_cast<std::size_t>(shape[0]) * shape[1] * shape[2];
  const auto K = static_cast<std::size_t>(gmf.gaussians);
  c.whole_need = memory.need(voxels, K);
  const bool fits = c.whole_need <= c.max_memory;
  if (gmf.stream_brick_voxels == 0 && fits && ranks <= 1) return c;  // today's fit
  c.bricked = true;
  const std::array<int, 3> halo = halo_voxels(frame, gmf.mahalanobis_cutoff, brick_max_scale(frame, gmf));
  const int smallest = std::max(16, 2 * *std::max_element(halo.begin(), halo.end()));
  int core = gmf.stream_brick_voxels > 0 ? gmf.stream_brick_voxels
                                         : largest_core(shape, smallest, c.max_memory, [&](int edge) {
                                             return memory.need(region_voxels(shape, edge, halo), K);
                                           });
  if (gmf.stream_brick_voxels == 0 && ranks > 1) {  // no brick size asked for: two or more per rank
    core = core_for_ranks(shape, ranks, core, smallest);
    c.for_ranks = true;
  }
  c.brick_need = memory.need(region_voxels(shape, core, halo), K);
  if (c.brick_need > c.max_memory) {
    throw io::InputError("gmf.max_memory = " + gmf.max_memory + ": too small for this fit: a brick of core " +
                         std::to_string(core) + " voxels with its halo (" + std::to_string(halo[0]) + " x " +
                         std::to_string(halo[1]) + " x " + std::to_string(halo[2]) + ") and a model of K " +
                         std::to_string(K) + " need " + io::gib_text(c.brick_need) + "; allow at least that");
  }
  double bricks = 1.0;  // counted before they are planned
  for (int a = 0; a < 3; ++a) bricks *= std::ceil(static_cast<double>(shape[a]) / core);
  if (bricks > GmfOptions::kMostStreamBricks) {
    throw io::InputError("gmf.stream_brick_voxels = " + std::to_string(core) + ": " + io::number_text(bricks) +
                         " bricks of core " + std::to_string(core) + " voxels for this stack, more than the limit of " +
                         std::to_string(GmfOptions::kMostStreamBricks) + "; use larger bricks (--brick-voxels)");
  }
  c.plan = plan_bricks(shape, {core, core, core}, halo);
  return c;
}

int core_for_ranks(const std::array<int, 3>& shape, int ranks, int start, int smallest) {
  const auto count = [&](int edge) {
    std::size_t n = 1;
    for (int a = 0; a < 3; ++a) n *= static_cast<std::size_t>((shape[a] + edge - 1) / edge);
    return n;
  };
  int core = start;
  while (core > smallest && count(core) < 2 * static_cast<std::size_t>(std::max(ranks, 1))) {
    core = std::max(smallest, (core * 3 / 4) / 16 * 16);
  }
  return core;
}

}  // namespace hisnegs::gmf
