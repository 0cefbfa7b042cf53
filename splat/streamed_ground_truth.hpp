// SPDX-License-Identifier: Apache-2.0
// Ground-truth MIPs of a stack read by regions (io::VolumeSource), for stacks larger
// than memory: the stack is cut into cores, each read with one voxel around it (what
// trilinear interpolation of its samples needs), and every ray's samples (exactly the
// whole marcher's: the same t0, step and index range from the whole box) are
// evaluated by the one core that owns the sample's voxel; the images are combined by
// a per-pixel max (a MIP is associative). Each sample is computed with the same float
// arithmetic as RayMarcher's, so the result equals the whole-stack march (tested bit
// for bit). CPU (TBB) only; no empty-space skipping inside a brick, an all-zero brick
// is skipped whole.
#pragma once

#include <functional>

#include "io/volume_source.hpp"
#include "splat/camera.hpp"
#include "splat/ground_truth.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

// Renders every view of `cameras` from `source`, normalized by `normalization`, in
// bricks of `core_voxels` (per axis, >= 1). `progress(done, total)` after each brick.
// With `marches`, only the bricks it accepts (by index, x fastest, then y, z) are
// read and marched: the images hold their part, and the element-wise max of the
// parts of bricks split among processes is the whole image (MPI's gt).
MipStack render_ground_truth_streamed(const io::VolumeSource& source, const io::Normalization& normalization,
                                      const io::WorldFrame& frame, const CameraSet& cameras,
                                      const RaymarchOptions& options, int core_voxels,
                                      const std::function<void(int, int)>& progress = {},
                                      const std::function<bool(int brick)>& marches = {});

}  // namespace hisnegs::splat
