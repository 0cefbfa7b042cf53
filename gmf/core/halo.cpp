// SPDX-License-Identifier: Apache-2.0
// stack_noise and count_halos (gmf/core/halo.hpp).
#include "gmf/core/halo.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace hisnegs::gmf {
namespace {

double median_of(std::vector<float>& values) {
  const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

}  // namespace

double stack_noise(const io::Volume& v) {
  if (v.size() == 0) throw std::invalid_argument("stack_noise: empty volume");
  std::vector<float> deviation;  // background voxels with six neighbours: V − their mean
  for (int z = 1; z + 1 < v.nz; ++z) {
    for (int y = 1; y + 1 < v.ny; ++y) {
      for (int x = 1; x + 1 < v.nx; ++x) {
        const float c = v.at(x, y, z);
        if (!(c < kHaloBackgroundLevel)) continue;
        const float mean = (v.at(x - 1, y, z) + v.at(x + 1, y, z) + v.at(x, y - 1, z) + v.at(x, y + 1, z) +
                            v.at(x, y, z - 1) + v.at(x, y, z + 1)) / 6.0f;
        deviation.push_back(c - mean);
      }
    }
  }
  if (deviation.empty()) return kHaloMinNoise;
  const double centre = median_of(deviation);
  for (float& d : deviation) d = static_cast<float>(std::abs(d - centre));
  const double sigma = 1.4826 * median_of(deviation) * std::sqrt(6.0 / 7.0);
  return std::max(kHaloMinNoise, 3.0 * sigma);
}

HaloCount count_halos(const GaussianMixture& mixture, const io::Volume& normalized, const io::WorldFrame& frame,
                      double noise) {
  HaloCount count;
  count.gaussians = mixture.size();
  count.noise = noise;
  std::vector<char> halo(mixture.size(), 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mixture.size(), 4096), [&](const auto& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      const GaussianParams& g = mixture[k];
      const Eigen::Vector3d centre(g.mean[0], g.mean[1], g.mean[2]);
      halo[k] = intensity(g) > io::sample_trilinear(normalized, frame, centre) + noise ? 1 : 0;
    }
  });
  for (std::size_t k = 0; k < halo.size(); ++k) {
    if (halo[k]) count.which.push_back(k);
  }
  count.halos = count.which.size();
  return count;
}

}  // namespace hisnegs::gmf
