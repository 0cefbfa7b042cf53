// SPDX-License-Identifier: Apache-2.0
// JacobianProbe: a random sample block and Gaussians, one CostFunction per method.
#include "gmf/jacobian_probe.hpp"

#include <ceres/dynamic_autodiff_cost_function.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>

#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "gmf/detail/block_cost.hpp"

namespace hisnegs::gmf {
namespace {

struct ResidualsOnly {
  const detail::BlockCost* cost;
  bool operator()(double const* const* p, double* r) const { return cost->Evaluate(p, r, nullptr); }
};

}  // namespace

struct JacobianProbe::Impl {
  SampleSet samples;
  std::vector<std::array<double, kGaussianParamCount>> params;
  std::vector<double*> blocks;
  std::vector<std::uint32_t> ids;
  std::unique_ptr<detail::BlockCost> analytic;
  std::unique_ptr<ceres::CostFunction> cost;  // the method's; null for kAnalytic
  std::vector<std::vector<double>> J;
  std::vector<double*> jac;
  std::vector<double> r;

  [[nodiscard]] const ceres::CostFunction& active() const { return cost ? *cost : *analytic; }
};

JacobianProbe::JacobianProbe(int n_samples, int n_gaussians, JacobianMethod method, std::uint64_t seed)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1), v(0, 1);
  d.samples.block_begin = {0, static_cast<std::uint32_t>(n_samples)};
  d.samples.block_origin = {{0, 0, 0}};
  d.samples.block = 4;
  for (int i = 0; i < n_samples; ++i) {
    d.samples.x.push_back(0.02 * u(rng));
    d.samples.y.push_back(0.02 * u(rng));
    d.samples.z.push_back(0.02 * u(rng));
    d.samples.value.push_back(v(rng));
    d.samples.weight.push_back(1.0);
  }
  d.params.resize(static_cast<std::size_t>(n_gaussians));
  for (auto& p : d.params) {
    for (int a = 0; a < 3; ++a) p[kMeanX + a] = 0.03 * u(rng);
    for (int a = 0; a < 3; ++a) p[kLogScale0 + a] = std::log(0.01 + 0.01 * v(rng));
    for (int a = 0; a < 4; ++a) p[kRotW + a] = u(rng) + (a == 0 ? 1.5 : 0.0);
    p[kLogit] = u(rng);
  }
  for (auto& p : d.params) {
    d.blocks.push_back(p.data());
    d.ids.push_back(static_cast<std::uint32_t>(d.ids.size()));
  }
  d.analytic = std::make_unique<detail::BlockCost>(d.samples, 0, d.ids.size(), MixtureModel{});
  if (method == JacobianMethod::kNumericCentral) {
    auto numeric = std::make_unique<ceres::DynamicNumericDiffCostFunction<ResidualsOnly, ceres::CENTRAL>>(
        new ResidualsOnly{d.analytic.get()});
    for (int size : d.analytic->parameter_block_sizes()) numeric->AddParameterBlock(size);
    numeric->SetNumResiduals(d.analytic->num_residuals());
    d.cost = std::move(numeric);
  } else if (method == JacobianMethod::kAutoDiff) {
    auto* functor = new detail::BlockResiduals{
        &d.samples, 0, static_cast<std::uint32_t>(n_samples), d.params.size(), MixtureModel{}, {}};
    auto autodiff = std::make_unique<ceres::DynamicAutoDiffCostFunction<detail::BlockResiduals, 4>>(functor);
    for (int size : d.analytic->parameter_block_sizes()) autodiff->AddParameterBlock(size);
    autodiff->SetNumResiduals(d.analytic->num_residuals());
    d.cost = std::move(autodiff);
  }
  const ceres::CostFunction& c = d.active();
  for (int size : c.parameter_block_sizes()) {
    d.J.emplace_back(static_cast<std::size_t>(c.num_residuals()) * size);
    d.jac.push_back(d.J.back().data());
  }
  d.r.resize(static_cast<std::size_t>(c.num_residuals()));
}

JacobianProbe::~JacobianProbe() = default;

double JacobianProbe::evaluate() {
  Impl& d = *impl_;
  d.active().Evaluate(d.blocks.data(), d.r.data(), d.jac.data());
  return d.r.empty() ? 0.0 : d.r[0];
}

int JacobianProbe::residuals() const { return impl_->active().num_residuals(); }

int JacobianProbe::parameters() const { return static_cast<int>(impl_->params.size()) * kGaussianParamCount; }

}  // namespace hisnegs::gmf
