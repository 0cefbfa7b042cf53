// SPDX-License-Identifier: Apache-2.0
// io::Progress under the name the pipeline's stages use.
#pragma once

#include "io/progress.hpp"

namespace hisnegs::apps {

using io::Progress;

}  // namespace hisnegs::apps
