// SPDX-License-Identifier: Apache-2.0
// The processes of one job: this process alone, or the ranks of an MPI launch
// (`mpirun -np N hisnegs ...`, `srun hisnegs ...`). A launch is detected from the
// variables the launchers set (Open MPI's OMPI_COMM_WORLD_SIZE, PMIx's and Slurm's
// PMI_SIZE / SLURM_NTASKS with a PMI rank): with more than one rank, the first
// call of job() initializes MPI, and MPI is finalized when the process exits.
// Built without MPI (HISNEGS_HAVE_MPI 0), a launch of several ranks is refused:
// each would do the whole work.
//
// What runs distributed and how (README "On a cluster"): the brick fit (each rank
// fits its share of the bricks into the shared brick folder, the seam pass colour
// by colour; rank 0 writes the checkpoint), the ground truth by bricks (each rank
// marches its bricks; the images meet in an element-wise max on rank 0), the
// render (shares of the Gaussians; max or merged softmax states) and training
// (data parallel over each step's views; gradients summed in rank order).
#pragma once

#include <functional>
#include <span>
#include <string>
#include <vector>

#include "gmf/bricked/collective.hpp"
#include "io/volume_source.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::apps {

// The job: the bricked fit's Collective (gmf/bricked/collective.hpp) and what the
// render adds to it.
class Job : public gmf::Collective {
 public:
  // pixels[i] = splat::merge_soft_pixel over the ranks' pixels[i], on rank 0 (a
  // custom MPI operation, applied in rank order: the same result on every run with
  // the same number of ranks). The other ranks' pixels are left as they were.
  virtual void merge_soft_to_root(std::span<splat::SoftPixel> pixels) const = 0;
};

// The job of this process (initializes MPI on the first call of a launch of
// several ranks). Throws io::InputError when launched on several ranks by a build
// without MPI, or when MPI cannot start.
[[nodiscard]] const Job& job();

// The ranks the launcher says this process is one of (1 when not launched by one).
[[nodiscard]] int launched_ranks();

// Runs `open` (opening the inputs: the volume, a checkpoint, a ground truth) on every
// rank of `job` and then agrees on it: a rank where it throws rethrows (its one-line
// error ends the job), the others wait for that end, so no rank starts work the job
// will not finish. Alone: open().
void open_on_every_rank(const Job& job, const std::function<void()>& open);

using gmf::scan_share;

// "rank 1 of 4: " when distributed, else "".
[[nodiscard]] std::string rank_prefix(const Job& job);

}  // namespace hisnegs::apps
