// SPDX-License-Identifier: Apache-2.0
// The processes a bricked fit runs on, as the fit sees them: this process alone, or
// the ranks of an MPI launch. The fitting layer knows no MPI: apps' job
// (apps/pipeline/distributed.hpp) implements this seam, alone or over MPI, and the
// bricked fit (gmf/bricked/bricked_fit.hpp) takes one.
#pragma once

#include <span>
#include <vector>

#include "io/volume_source.hpp"

namespace hisnegs::gmf {

class Collective {
 public:
  virtual ~Collective() = default;
  [[nodiscard]] virtual int rank() const = 0;
  [[nodiscard]] virtual int size() const = 0;
  [[nodiscard]] bool root() const { return rank() == 0; }
  [[nodiscard]] bool distributed() const { return size() > 1; }
  // Waits for every rank.
  virtual void barrier() const = 0;
  // values[i] = the max of values[i] over the ranks, on rank 0 (exact, so the result
  // does not depend on the number of ranks). The other ranks' values are left as
  // they were.
  virtual void max_to_root(std::span<float> values) const = 0;
  // values[i] = the sum of values[i] over the ranks, on every rank, identical bits on
  // each: reduced in rank order to rank 0, then broadcast. Deterministic for a given
  // number of ranks; a float sum in another order than one process's, so not
  // bit-equal to it.
  virtual void sum_all(std::span<float> values) const = 0;
  virtual void sum_all(std::span<double> values) const = 0;
  // values[i] = the max of values[i] over the ranks, on every rank (exact).
  virtual void max_all(std::span<double> values) const = 0;
  // Rank 0's values on every rank.
  virtual void broadcast(std::span<double> values) const = 0;
  // Rank `root`'s bytes (and their count) on every rank.
  virtual void broadcast(std::vector<unsigned char>& bytes, int root) const = 0;
  // Point to point: to[r] goes to rank r (to[rank()] is not sent); returns what
  // each rank sent this one (from[r], empty from this rank and from a rank that sent
  // nothing). Every rank must call it. Alone: a list of one empty entry.
  [[nodiscard]] virtual std::vector<std::vector<unsigned char>> exchange(
      const std::vector<std::vector<unsigned char>>& to) const = 0;
  // Ends every rank with `code`: a rank that fails must not leave the others
  // waiting for it. Alone: std::exit(code).
  [[noreturn]] virtual void abort(int code) const = 0;
};

// The ranks of `ranks` scanning a stack's statistics together (io::ScanShare): each
// reads its share of the pages; the counts and extremes meet exactly.
[[nodiscard]] io::ScanShare scan_share(const Collective& ranks);

}  // namespace hisnegs::gmf
