// SPDX-License-Identifier: Apache-2.0
// scan_share.
#include "gmf/bricked/collective.hpp"

namespace hisnegs::gmf {

io::ScanShare scan_share(const Collective& ranks) {
  io::ScanShare share;
  share.part = ranks.rank();
  share.parts = ranks.size();
  share.sum = [&ranks](std::span<double> values) { ranks.sum_all(values); };
  share.max = [&ranks](std::span<double> values) { ranks.max_all(values); };
  return share;
}

}  // namespace hisnegs::gmf
