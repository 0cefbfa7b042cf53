// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the cameras.json reader: read_cameras_json, and for every
// accepted file a write/read round trip, which must reproduce it exactly.
// Only io::InputError may escape; anything else is a finding.
#include <cstddef>
#include <cstdint>

#include "fuzz/fuzz_support.hpp"
#include "splat/camera.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const std::filesystem::path path = fuzz::write_input("cameras.json", data, size);
  splat::CameraSet cameras;
  try {
    cameras = splat::read_cameras_json(path);
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
    return 0;
  }
  const std::filesystem::path again = fuzz::scratch_dir() / "round_trip.json";
  splat::write_cameras_json(again, cameras);
  const splat::CameraSet reread = splat::read_cameras_json(again);
  const splat::Intrinsics &a = cameras.intrinsics, &b = reread.intrinsics;
  fuzz::require(a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
                    a.cy == b.cy && a.near == b.near && a.far == b.far,
                "intrinsics round-trip exactly");
  fuzz::require(reread.views.size() == cameras.views.size(), "view count round-trips");
  for (std::size_t i = 0; i < cameras.views.size(); ++i) {
    const splat::CameraView &u = cameras.views[i], &w = reread.views[i];
    fuzz::require(
        u.name == w.name && u.R_cam_from_world == w.R_cam_from_world && u.t_cam_from_world == w.t_cam_from_world,
        "views round-trip exactly");
  }
  return 0;
}
