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

#include "io/volume_source.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::apps {

class Job {
 public:
  virtual ~Job() = default;
  [[nodiscard]] virtual int rank() const = 0;
  [[nodiscard]] virtual int size() const = 0;
  [[nodiscard]] bool root() const { return rank() == 0; }
  [[nodiscard]] bool distributed() const { return size() > 1; }
  // Waits for every rank.
  virtual void barrier() const = 0;
  // values[i] = the max of values[i] over the ranks, on rank 0 (MPI_Reduce with
  // MPI_MAX: exact, so the result does not depend on the number of ranks). The
  // other ranks' values are left as they were.
  virtual void max_to_root(std::span<float> values) const = 0;
  // pixels[i] = splat::merge_soft_pixel over the ranks' pixels[i], on rank 0 (a
  // custom MPI operation, applied in rank order: the same result on every run with
  // the same number of ranks). The other ranks' pixels are left as they were.
  virtual void merge_soft_to_root(std::span<splat::SoftPixel> pixels) const = 0;
  // values[i] = the sum of values[i] over the ranks, on every rank, identical bits on
  // each: reduced in rank order (a non-commutative MPI operation) to rank 0, then
  // broadcast. Deterministic for a given number of ranks; a float sum in another
  // order than one process's, so not bit-equal to it.
  virtual void sum_all(std::span<float> values) const = 0;
  virtual void sum_all(std::span<double> values) const = 0;
  // values[i] = the max of values[i] over the ranks, on every rank (MPI_Allreduce
  // with MPI_MAX: exact).
  virtual void max_all(std::span<double> values) const = 0;
  // Rank 0's values on every rank.
  virtual void broadcast(std::span<double> values) const = 0;
  // Rank `root`'s bytes (and their count) on every rank.
  virtual void broadcast(std::vector<unsigned char>& bytes, int root) const = 0;
  // Point to point: to[r] goes to rank r (to[rank()] is not sent); returns what
  // each rank sent this one (from[r], empty from this rank and from a rank that sent
  // nothing). Every rank must call it. MPI_Alltoall of the sizes, then
  // MPI_Isend/MPI_Irecv of the bytes. Alone: a list of one empty entry.
  [[nodiscard]] virtual std::vector<std::vector<unsigned char>> exchange(
      const std::vector<std::vector<unsigned char>>& to) const = 0;
  // Ends every rank of the job with `code` (MPI_Abort): a rank that fails must not
  // leave the others waiting for it. Alone: std::exit(code).
  [[noreturn]] virtual void abort(int code) const = 0;
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

// The ranks of `job` scanning a stack's statistics together (io::ScanShare): each
// reads its share of the pages; the counts and extremes meet exactly.
[[nodiscard]] io::ScanShare scan_share(const Job& job);

// "rank 1 of 4: " when distributed, else "".
[[nodiscard]] std::string rank_prefix(const Job& job);

}  // namespace hisnegs::apps
