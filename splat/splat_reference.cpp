// SPDX-License-Identifier: Apache-2.0
// render_reference / render_reference_backward: two passes per pixel (max, then
// the softmax sums) in double, over all K, and the chain of splat_math.hpp.
#include "splat/splat_reference.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace hisnegs::splat {
namespace {

struct Projected {
  std::vector<Splat2D<double>> splats;
  std::vector<ProjectionCache<double>> caches;
};

Projected project_all(std::span<const double> params, const ViewParams<double>& view, const SplatSettings& s) {
  const std::size_t K = params.size() / gmf::kGaussianParamCount;
  Projected p;
  p.splats.resize(K);
  p.caches.resize(K);
  for (std::size_t k = 0; k < K; ++k) {
    p.splats[k] = project_gaussian(&params[gmf::kGaussianParamCount * k], view, double(s.cutoff), double(s.low_pass),
                                   &p.caches[k]);
  }
  return p;
}

// The g_k of the Gaussians touching pixel (px, py): (index, g).
void touching(const Projected& p, double px, double py, double cutoff,
              std::vector<std::pair<std::size_t, double>>& out) {
  out.clear();
  for (std::size_t k = 0; k < p.splats.size(); ++k) {
    const Splat2D<double>& s = p.splats[k];
    if (!s.visible) continue;
    const double q = splat_distance(s, px, py);
    if (q <= cutoff) out.emplace_back(k, s.amplitude * std::exp(-0.5 * q));
  }
}

// The floor at pixel (r, c) (splat_renderer.hpp SplatSettings::floor), 0 when none.
double floor_at(const SplatSettings& settings, int width, int r, int c) {
  return settings.floor.empty() ? 0.0 : settings.floor[static_cast<std::size_t>(r) * width + c];
}

}  // namespace

std::vector<double> render_reference(std::span<const double> params, const ViewParams<double>& view,
                                     const SplatSettings& settings) {
  const Projected p = project_all(params, view, settings);
  std::vector<double> image(static_cast<std::size_t>(view.width) * view.height, 0.0);
  std::vector<std::pair<std::size_t, double>> terms;
  const double beta = settings.beta;
  for (int r = 0; r < view.height; ++r) {
    for (int c = 0; c < view.width; ++c) {
      touching(p, c + 0.5, r + 0.5, settings.cutoff, terms);
      const double b = floor_at(settings, view.width, r, c);
      double& pixel = image[static_cast<std::size_t>(r) * view.width + c];
      pixel = b;  // max(splat, floor); the splat is 0 where nothing reaches
      if (terms.empty()) continue;
      double g_max = -std::numeric_limits<double>::infinity();
      for (const auto& [k, g] : terms) g_max = std::max(g_max, g);
      double value = g_max;
      if (settings.mode == MipMode::kSoftmax) {
        double S = 0, W = 0;
        for (const auto& [k, g] : terms) {
          const double e = std::exp(beta * (g - g_max));
          S += e;
          W += e * g;
        }
        value = W / S;
      }
      pixel = std::max(value, b);
    }
  }
  return image;
}

std::vector<double> render_reference_backward(std::span<const double> params, const ViewParams<double>& view,
                                              const SplatSettings& settings, std::span<const double> dL_dimage,
                                              std::vector<double>* screen_grad) {
  const Projected p = project_all(params, view, settings);
  const std::size_t K = p.splats.size();
  std::vector<Splat2DGrad<double>> grads(K);
  std::vector<std::pair<std::size_t, double>> terms;
  const double beta = settings.beta;
  for (int r = 0; r < view.height; ++r) {
    for (int c = 0; c < view.width; ++c) {
      const double dL_dI = dL_dimage[static_cast<std::size_t>(r) * view.width + c];
      if (dL_dI == 0.0) continue;
      const double px = c + 0.5, py = r + 0.5;
      touching(p, px, py, settings.cutoff, terms);
      if (terms.empty()) continue;
      if (!settings.soft()) {  // the max's subgradient: the first largest term, unless the floor is at least it
        auto top = terms.begin();
        for (auto t = terms.begin(); t != terms.end(); ++t) {
          if (t->second > top->second) top = t;
        }
        if (floor_at(settings, view.width, r, c) < top->second) {
          accumulate_pixel_grad(p.splats[top->first], px, py, dL_dI, grads[top->first]);
        }
        continue;
      }
      double m = -std::numeric_limits<double>::infinity();
      for (const auto& [k, g] : terms) m = std::max(m, beta * g);
      double S = 0, W = 0;
      for (const auto& [k, g] : terms) {
        const double e = std::exp(beta * g - m);
        S += e;
        W += e * g;
      }
      const double I = W / S;
      if (floor_at(settings, view.width, r, c) > I) continue;  // the floor won the max: no gradient
      for (const auto& [k, g] : terms) {
        accumulate_pixel_grad(p.splats[k], px, py, dL_dI * gmf::softmax_dvalue_dterm(g, beta, m, S, I), grads[k]);
      }
    }
  }
  std::vector<double> out(params.size(), 0.0);
  if (screen_grad != nullptr) screen_grad->assign(K, 0.0);
  for (std::size_t k = 0; k < K; ++k) {
    if (!p.splats[k].visible) continue;
    project_gaussian_backward(&params[gmf::kGaussianParamCount * k], view, p.caches[k], grads[k],
                              &out[gmf::kGaussianParamCount * k]);
    if (screen_grad != nullptr) (*screen_grad)[k] = std::hypot(grads[k].u, grads[k].v);
  }
  return out;
}

}  // namespace hisnegs::splat
