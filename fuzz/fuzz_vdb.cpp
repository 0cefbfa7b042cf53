// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the .vdb readers: inspect_vdb (`hisnegs info`), then
// read_vdb (the sparse grid `fit` reads) on the same bytes. Both walk the file
// first (io/vdb_validate.hpp); OpenVDB then reads the values only of the grids whose
// leaf buffers the walk checked, and the metadata of the others. Only io::InputError
// may escape; a crash, a sanitizer report or an allocation beyond libFuzzer's
// -malloc_limit_mb (OpenVDB trusting a size the walk let through) is a finding.
#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_support.hpp"
#include "io/sparse_grid.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const std::filesystem::path path = fuzz::write_input("grid.vdb", data, size);
  try {
    const std::vector<io::VdbGridSummary> grids = io::inspect_vdb(path);
    for (const io::VdbGridSummary& g : grids) {
      fuzz::require(g.active_voxels >= -1, "active voxel counts are >= 0 or -1 (not recorded)");
      fuzz::require(g.values_read || g.memory_bytes >= -1, "memory is >= 0 or -1 (not recorded)");
    }
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
  }
  try {
    const io::SparseGrid grid = io::read_vdb(path);
    const auto& shape = grid.meta().shape_xyz;
    fuzz::require(shape[0] > 0 && shape[1] > 0 && shape[2] > 0, "a grid that loaded has a positive shape");
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
  }
  return 0;
}
