// SPDX-License-Identifier: Apache-2.0
// mean_squared_error in fixed chunks summed in chunk order (TBB over chunks), psnr.
#include "gmf/psnr.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

namespace hisnegs::gmf {

double mean_squared_error(std::span<const float> values, std::span<const float> reference) {
  if (values.size() != reference.size() || values.empty()) {
    throw std::invalid_argument("mean_squared_error: arrays of " + std::to_string(values.size()) + " and " +
                                std::to_string(reference.size()) + " values");
  }
  // Fixed chunk boundaries, each summed in order, then the chunks in order: the
  // result does not depend on how TBB schedules them.
  constexpr std::size_t kChunk = std::size_t{1} << 16;
  const std::size_t chunks = (values.size() + kChunk - 1) / kChunk;
  std::vector<double> sums(chunks, 0.0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks), [&](const auto& r) {
    for (std::size_t c = r.begin(); c != r.end(); ++c) {
      const std::size_t end = std::min(values.size(), (c + 1) * kChunk);
      double se = 0.0;
      for (std::size_t i = c * kChunk; i < end; ++i) {
        const double d = static_cast<double>(values[i]) - reference[i];
        se += d * d;
      }
      sums[c] = se;
    }
  });
  return std::accumulate(sums.begin(), sums.end(), 0.0) / static_cast<double>(values.size());
}

double psnr_from_mse(double mse) {
  return mse > 0.0 ? 10.0 * std::log10(1.0 / mse) : std::numeric_limits<double>::infinity();
}

double psnr(std::span<const float> values, std::span<const float> reference) {
  return psnr_from_mse(mean_squared_error(values, reference));
}

}  // namespace hisnegs::gmf
