// SPDX-License-Identifier: Apache-2.0
// mean_squared_error and sum_of_squares in fixed chunks summed in chunk order (TBB over chunks), psnr.
#include "gmf/core/psnr.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

namespace hisnegs::gmf {

namespace {

// Σ_i term(i) over [0, n) in fixed chunks, each summed in order, then the chunks in
// order: the result does not depend on how TBB schedules them.
template <class Term>
double chunked_sum(std::size_t n, Term term) {
  constexpr std::size_t kChunk = std::size_t{1} << 16;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<double> sums(chunks, 0.0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks), [&](const auto& r) {
    for (std::size_t c = r.begin(); c != r.end(); ++c) {
      const std::size_t end = std::min(n, (c + 1) * kChunk);
      double sum = 0.0;
      for (std::size_t i = c * kChunk; i < end; ++i) sum += term(i);
      sums[c] = sum;
    }
  });
  return std::accumulate(sums.begin(), sums.end(), 0.0);
}

}  // namespace

double mean_squared_error(std::span<const float> values, std::span<const float> reference) {
  if (values.size() != reference.size() || values.empty()) {
    throw std::invalid_argument("mean_squared_error: arrays of " + std::to_string(values.size()) + " and " +
                                std::to_string(reference.size()) + " values");
  }
  const double se = chunked_sum(values.size(), [&](std::size_t i) {
    const double d = static_cast<double>(values[i]) - reference[i];
    return d * d;
  });
  return se / static_cast<double>(values.size());
}

double sum_of_squares(std::span<const float> values) {
  return chunked_sum(values.size(), [&](std::size_t i) { return static_cast<double>(values[i]) * values[i]; });
}

double psnr_from_mse(double mse) {
  return mse > 0.0 ? 10.0 * std::log10(1.0 / mse) : std::numeric_limits<double>::infinity();
}

double psnr(std::span<const float> values, std::span<const float> reference) {
  return psnr_from_mse(mean_squared_error(values, reference));
}

}  // namespace hisnegs::gmf
