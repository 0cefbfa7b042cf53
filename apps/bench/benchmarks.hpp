// SPDX-License-Identifier: Apache-2.0
// Google Benchmark suites run by `hisnegs bench SUITE`. Each registers its
// benchmarks; cmd_bench runs them. Timings are wall clock (UseRealTime) since
// the code under test is TBB-parallel.
#pragma once

#include <filesystem>
#include <vector>

#include "gmf/gmf_options.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"

namespace hisnegs::apps::bench {

// Loading, normalizing and sparsifying `volume` (a TIFF stack).
void register_io_benchmarks(const std::filesystem::path& volume);

// Ground-truth MIPs of the 30 evaluation views at size × size, both modes, CPU and
// (when available) CUDA; iterations = whole orbits, counter median_ms_per_view.
void register_gt_benchmarks(const std::filesystem::path& volume, int size);

// Splatting: hard, soft and backward against resolution (K = 50k), against K at
// 256², and soft against β, on Table 3-shaped synthetic mixtures.
void register_render_benchmarks(const std::vector<int>& sizes, const std::vector<int>& gaussian_counts,
                                const std::vector<float>& betas);

// One GMF residual block with its Jacobian: analytic vs numeric vs automatic.
void register_gmf_benchmarks();

// The stage-1 objective's value and gradient at `model` on `volume`'s fit samples,
// the block index rebuilt per call, as hisnegs.Objective.gradient does.
void register_objective_benchmark(const std::filesystem::path& volume, const std::filesystem::path& model,
                                  const io::VolumeOptions& volume_options, const io::SparseGridOptions& sparse_grid,
                                  const gmf::GmfOptions& gmf);

}  // namespace hisnegs::apps::bench
