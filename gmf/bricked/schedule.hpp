// SPDX-License-Identifier: Apache-2.0
// How the bricks of a plan are shared among ranks and what each costs: the
// deterministic heaviest-first assignment, the work models measured on this
// repository's stacks, each brick's foreground from one pass of slabs, and which
// Gaussians the seam pass refits.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "gmf/bricked/brick_plan.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::gmf {

// The rank (of `ranks`) that takes each of `ids`: heaviest by `weight` first, each
// to the rank with the least weight so far; deterministic, all 0 alone.
[[nodiscard]] std::vector<int> brick_ranks(const std::vector<int>& ids, int ranks,
                                           const std::function<double(int)>& weight);
// The bricks of `todo` (ids into a plan's bricks) that `rank` of `ranks` fits, shared
// by `weight` (brick_ranks); all of them alone.
[[nodiscard]] std::vector<int> share_of_bricks(const std::vector<int>& todo, const std::function<double(int)>& weight,
                                               int rank, int ranks);
// What fitting a brick costs, in foreground voxels: those of its core plus its core's
// reading (a voxel read and sampled costs about 1/4000 of a foreground voxel fitted:
// 0.37 µs against ~1.4 ms on one core, docs/benchmarks.md "Several MPI ranks").
[[nodiscard]] double brick_work(double core_foreground, double core_voxels);
// The foreground voxels (above `threshold` once normalized by `map`) of every
// brick's core of plan `p`, by brick id, from one pass of slabs of pages (this
// part's share when shared; the exact counts summed). What the ranks share the
// brick pass by: a brick's own region read would cost more (a region of a striped
// or tiled file decodes whole strips or tiles).
[[nodiscard]] std::vector<std::int64_t> core_foreground_counts(const io::VolumeSource& source,
                                                               const io::Normalization& map, const BrickPlan& p,
                                                               double threshold, std::size_t slab,
                                                               const io::ScanShare& share = {});
// What measuring a brick's 3D error costs, in voxels: its core's (read, rendered
// and compared) plus its Gaussians' (a Gaussian rendered costs about 2,000 voxels:
// ~20 µs against ~8 ns on one core, from the measuring passes of op1 and the
// largest stack, docs/benchmarks.md "Several MPI ranks").
[[nodiscard]] double measure_work(double region_voxels, double gaussians);
// True when g's support (dᵀΣ⁻¹d <= `cutoff`: along axis a it extends sqrt(δ Σ_aa))
// reaches a face of brick b's core that another brick of `p` shares, with a margin
// for one round's growth (x 1.25) and a voxel, never beyond the halo: the Gaussians
// the seam pass refits. Two Gaussians of neighbouring bricks whose supports overlap
// have one of them reaching across the face between them (the overlap lies on one
// side of it), and that one is refitted with the other held; a Gaussian whose
// support stays inside its core meets the neighbour's only there.
[[nodiscard]] bool reaches_shared_face(const BrickPlan& p, const io::WorldFrame& frame, double cutoff,
                                       const StreamBrick& b, const GaussianParams& g);

}  // namespace hisnegs::gmf
