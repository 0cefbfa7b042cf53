// SPDX-License-Identifier: Apache-2.0
// The text helpers of io/text.hpp under the names the pipeline uses.
#pragma once

#include "io/text.hpp"

namespace hisnegs::apps {

using io::format_bytes;
using io::format_seconds;
using io::strf;
using io::vstrf;

}  // namespace hisnegs::apps
