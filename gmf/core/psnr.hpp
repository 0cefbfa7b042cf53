// SPDX-License-Identifier: Apache-2.0
// The one PSNR of hisnegs (CONVENTIONS "Metrics", data range 1): 10 log10(1 / MSE)
// of any two equally long arrays, images or volumes alike, with a deterministic
// reduction (the same value for any thread count). No other metric here.
#pragma once

#include <span>

namespace hisnegs::gmf {

// Mean of (values − reference)² in double. Throws std::invalid_argument for arrays
// of different or zero length.
[[nodiscard]] double mean_squared_error(std::span<const float> values, std::span<const float> reference);

// Σ values² in double, reduced like mean_squared_error (any thread count, same value).
[[nodiscard]] double sum_of_squares(std::span<const float> values);

// 10 log10(1 / mse) in dB; +infinity for mse = 0 (identical arrays).
[[nodiscard]] double psnr_from_mse(double mse);

// psnr_from_mse(mean_squared_error(values, reference)).
[[nodiscard]] double psnr(std::span<const float> values, std::span<const float> reference);

}  // namespace hisnegs::gmf
