// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the PLY checkpoint reader: load_checkpoint (io::read_ply +
// gmf::checkpoint_from_ply), and for every accepted file a save/load round trip,
// which must reproduce it exactly. Only io::InputError may escape; anything else is a finding.
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "fuzz/fuzz_support.hpp"
#include "gmf/core/checkpoint.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const std::filesystem::path path = fuzz::write_input("checkpoint.ply", data, size);
  gmf::Checkpoint loaded;
  try {
    loaded = gmf::load_checkpoint(path);
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
    return 0;
  }
  // save_checkpoint throws std::invalid_argument for what it could not read
  // back; a checkpoint that loaded must never be one of those.
  const std::filesystem::path again = fuzz::scratch_dir() / "round_trip.ply";
  gmf::save_checkpoint(again, loaded.mixture, loaded.meta);
  const gmf::Checkpoint reread = gmf::load_checkpoint(again);
  fuzz::require(reread.meta == loaded.meta, "checkpoint metadata round-trips");
  fuzz::require(reread.mixture.size() == loaded.mixture.size() &&
                    (loaded.mixture.empty() || std::memcmp(reread.mixture.data(), loaded.mixture.data(),
                                                           loaded.mixture.size() * sizeof(gmf::GaussianParams)) == 0),
                "checkpoint Gaussians round-trip bit-exactly");
  return 0;
}
