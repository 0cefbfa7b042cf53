// SPDX-License-Identifier: Apache-2.0
// The layout of one Gaussian's 11 parameters (CONVENTIONS "Gaussians"): their
// order in memory, in checkpoints and in every gradient, and the optimizer groups
// they belong to. The one place the parameter count is defined. No math here.
#pragma once

#include "gmf/core/hd.hpp"

namespace hisnegs::gmf {

// Parameter order of every flat array and gradient (== PLY property order).
enum GaussianParam : int {
  kMeanX = 0,
  kMeanY,
  kMeanZ,
  kLogScale0,
  kLogScale1,
  kLogScale2,
  kRotW,
  kRotX,
  kRotY,
  kRotZ,
  kLogit
};
// The number of parameters of one Gaussian: the only such constant.
inline constexpr int kGaussianParamCount = kLogit + 1;

// The optimizers' parameter groups (each gets its own learning rate).
enum ParamGroup : int { kGroupMeans = 0, kGroupLogScales, kGroupRotation, kGroupIntensity, kParamGroupCount };

// Group of parameter `param` (0 <= param < kGaussianParamCount).
HISNEGS_HD constexpr ParamGroup group_of(int param) {
  return param <= kMeanZ       ? kGroupMeans
         : param <= kLogScale2 ? kGroupLogScales
         : param <= kRotZ      ? kGroupRotation
                               : kGroupIntensity;
}

}  // namespace hisnegs::gmf
