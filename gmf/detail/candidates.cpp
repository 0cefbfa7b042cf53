// SPDX-License-Identifier: Apache-2.0
// candidate_distances and shifted_exp, compiled once per instruction set by
// Highway (foreach_target) and dispatched at run time. Highway's Exp is within
// 1 ULP of std::exp for doubles.
// clang-format off
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "gmf/detail/candidates.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>
#include <hwy/contrib/math/math-inl.h>
// clang-format on

#include "gmf/detail/candidates.hpp"

HWY_BEFORE_NAMESPACE();
namespace hisnegs::gmf::detail {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

void CandidateDistances(const CandidatePack& pack, const double* x, double* m, double* e, double* z) {
  const hn::ScalableTag<double> d;
  const std::size_t N = hn::Lanes(d), stride = pack.stride;
  const auto x0 = hn::Set(d, x[0]), x1 = hn::Set(d, x[1]), x2 = hn::Set(d, x[2]);
  const auto half = hn::Set(d, -0.5);
  const double* f[CandidatePack::kFields];
  for (int i = 0; i < CandidatePack::kFields; ++i) f[i] = pack.field(i);
  for (std::size_t i = 0; i < pack.size; i += N) {
    const auto d0 = hn::Sub(x0, hn::LoadU(d, f[0] + i));
    const auto d1 = hn::Sub(x1, hn::LoadU(d, f[1] + i));
    const auto d2 = hn::Sub(x2, hn::LoadU(d, f[2] + i));
    const auto row = [&](int r) {
      return hn::MulAdd(hn::LoadU(d, f[3 + 3 * r] + i), d0,
                        hn::MulAdd(hn::LoadU(d, f[4 + 3 * r] + i), d1, hn::Mul(hn::LoadU(d, f[5 + 3 * r] + i), d2)));
    };
    const auto z0 = row(0), z1 = row(1), z2 = row(2);
    const auto mm = hn::MulAdd(z0, z0, hn::MulAdd(z1, z1, hn::Mul(z2, z2)));
    hn::StoreU(mm, d, m + i);
    hn::StoreU(hn::Exp(d, hn::Mul(half, mm)), d, e + i);
    hn::StoreU(z0, d, z + i);
    hn::StoreU(z1, d, z + stride + i);
    hn::StoreU(z2, d, z + 2 * stride + i);
  }
}

void CandidateSlack(const double* rows, const std::int64_t* offset, std::size_t n, const double* centre, double radius,
                    double reach, double* slack) {
  const hn::ScalableTag<double> d;
  const hn::RebindToSigned<decltype(d)> di;
  const std::size_t N = hn::Lanes(d);
  const auto c0 = hn::Set(d, centre[0]), c1 = hn::Set(d, centre[1]), c2 = hn::Set(d, centre[2]);
  const auto r = hn::Set(d, radius), reach_v = hn::Set(d, reach);
  for (std::size_t i = 0; i < n; i += N) {
    const auto at = hn::LoadU(di, offset + i);
    const auto field = [&](std::size_t f) { return hn::GatherIndex(d, rows + f, at); };
    const auto d0 = hn::Sub(c0, field(0)), d1 = hn::Sub(c1, field(1)), d2 = hn::Sub(c2, field(2));
    const auto row = [&](std::size_t k) {
      return hn::MulAdd(field(3 + 3 * k), d0, hn::MulAdd(field(4 + 3 * k), d1, hn::Mul(field(5 + 3 * k), d2)));
    };
    const auto z0 = row(0), z1 = row(1), z2 = row(2);
    const auto mm = hn::MulAdd(z0, z0, hn::MulAdd(z1, z1, hn::Mul(z2, z2)));
    const auto bound = hn::NegMulAdd(field(kRowMaxInvScale), r, hn::Sqrt(mm));
    hn::StoreU(hn::Sub(bound, reach_v), d, slack + i);
  }
}

void ShiftedExp(const double* v, std::size_t n, double scale, double shift, double* out) {
  const hn::ScalableTag<double> d;
  const std::size_t N = hn::Lanes(d);
  const auto s = hn::Set(d, scale), c = hn::Set(d, shift);
  for (std::size_t i = 0; i < n; i += N) {
    hn::StoreU(hn::Exp(d, hn::Mul(s, hn::Sub(hn::LoadU(d, v + i), c))), d, out + i);
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace hisnegs::gmf::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace hisnegs::gmf::detail {

HWY_EXPORT(CandidateDistances);
HWY_EXPORT(ShiftedExp);
HWY_EXPORT(CandidateSlack);

void CandidatePack::resize(std::size_t n) {
  size = n;
  stride = (n + kCandidateAlign - 1) / kCandidateAlign * kCandidateAlign;
  data.assign(static_cast<std::size_t>(kFields) * stride, 0.0);
}

void CandidatePack::assign(const double* rows, const std::uint32_t* ids, std::size_t n) {
  resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double* row = rows + ids[i] * kGaussianRow;
    for (int f = 0; f < kFields; ++f) field(f)[i] = row[f];
  }
}

void candidate_distances(const CandidatePack& pack, const double x[3], double* m, double* e, double* z) {
  HWY_DYNAMIC_DISPATCH(CandidateDistances)(pack, x, m, e, z);
}

void candidate_slack(const double* rows, const std::int64_t* offset, std::size_t n, const double centre[3],
                     double radius, double reach, double* slack) {
  HWY_DYNAMIC_DISPATCH(CandidateSlack)(rows, offset, n, centre, radius, reach, slack);
}

void shifted_exp(const double* v, std::size_t n, double scale, double shift, double* out) {
  HWY_DYNAMIC_DISPATCH(ShiftedExp)(v, n, scale, shift, out);
}

}  // namespace hisnegs::gmf::detail
#endif
