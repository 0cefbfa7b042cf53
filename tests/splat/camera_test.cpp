// SPDX-License-Identifier: Apache-2.0
// Cameras: intrinsics from the FOV, orbit poses per CONVENTIONS (including the
// poles), the 106/30-view orbits, projection vs ray direction, cameras.json.
#include "splat/camera.hpp"

#include <gtest/gtest.h>

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <numbers>

#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::splat {
namespace {

TEST(Camera, IntrinsicsFromFov) {
  const Intrinsics K = make_intrinsics(CameraOptions{});
  EXPECT_NEAR(K.fx, 128.0 / std::tan(25.0 * std::numbers::pi / 180.0), 1e-12);
  EXPECT_EQ(K.fx, K.fy);
  EXPECT_EQ(K.cx, 128.0);
  EXPECT_EQ(K.cy, 128.0);
  EXPECT_EQ(K.near, 0.01);
  EXPECT_EQ(K.far, 10.0);
}

TEST(Camera, OrbitPoseLooksAtTheOriginWithOpenCvAxes) {
  const CameraView v = orbit_view(30.0, 40.0, 2.5, "v");
  const double e = 30.0 * std::numbers::pi / 180, p = 40.0 * std::numbers::pi / 180;
  const Eigen::Vector3d C = 2.5 * Eigen::Vector3d(std::cos(e) * std::cos(p), std::cos(e) * std::sin(p), std::sin(e));
  EXPECT_TRUE(v.center_world().isApprox(C, 1e-12));
  const Eigen::Matrix3d& R = v.R_cam_from_world;
  EXPECT_TRUE((R * R.transpose()).isIdentity(1e-12));
  EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
  // The origin is straight ahead at depth r.
  const Eigen::Vector3d o = R * Eigen::Vector3d::Zero() + v.t_cam_from_world;
  EXPECT_NEAR(o.x(), 0.0, 1e-12);
  EXPECT_NEAR(o.y(), 0.0, 1e-12);
  EXPECT_NEAR(o.z(), 2.5, 1e-12);
  // x_c = normalize(z_c × up), up = +z: world +z points up in the image (negative camera y).
  EXPECT_LT((R * Eigen::Vector3d(0, 0, 1)).y(), 0.0);
  EXPECT_NEAR(R.row(0).z(), 0.0, 1e-12);  // x_c is horizontal
}

TEST(Camera, PolesAreWellDefined) {
  for (double e : {90.0, -90.0, 89.99, -89.99}) {
    const CameraView v = orbit_view(e, 10.0, 2.5, "pole");
    const Eigen::Matrix3d& R = v.R_cam_from_world;
    ASSERT_TRUE(R.allFinite()) << e;
    EXPECT_TRUE((R * R.transpose()).isIdentity(1e-9)) << e;
    EXPECT_NEAR(R.determinant(), 1.0, 1e-9) << e;
    const Eigen::Vector3d o = R * Eigen::Vector3d::Zero() + v.t_cam_from_world;
    EXPECT_NEAR(o.z(), 2.5, 1e-9) << e;
  }
}

TEST(Camera, TrainingAndEvaluationOrbits) {
  const CameraSet train = training_orbit(CameraOptions{});
  ASSERT_EQ(train.views.size(), 106u);
  EXPECT_EQ(train.views.front().name, "train_000");
  // Ring 1 (e = 0) is offset by half a step: its first azimuth is 360 * 0.5 / 27.
  const Eigen::Vector3d c27 = train.views[27].center_world();
  EXPECT_NEAR(std::atan2(c27.y(), c27.x()) * 180 / std::numbers::pi, 360.0 * 0.5 / 27, 1e-9);
  EXPECT_NEAR(c27.z(), 0.0, 1e-12);
  // Ring 3 (e = 60, 26 views) starts at 360 * 0.5 / 26.
  const Eigen::Vector3d c80 = train.views[80].center_world();
  EXPECT_NEAR(std::asin(c80.z() / 2.5) * 180 / std::numbers::pi, 60.0, 1e-9);
  EXPECT_NEAR(std::atan2(c80.y(), c80.x()) * 180 / std::numbers::pi, 360.0 * 0.5 / 26, 1e-9);
  const CameraSet eval = evaluation_orbit(CameraOptions{});
  ASSERT_EQ(eval.views.size(), 30u);
  const Eigen::Vector3d e0 = eval.views[0].center_world();
  EXPECT_NEAR(std::asin(e0.z() / 2.5) * 180 / std::numbers::pi, -15.0, 1e-9);
  EXPECT_NEAR(std::atan2(e0.y(), e0.x()) * 180 / std::numbers::pi, 18.0, 1e-9);
  const Eigen::Vector3d e29 = eval.views[29].center_world();
  EXPECT_NEAR(std::asin(e29.z() / 2.5) * 180 / std::numbers::pi, 45.0, 1e-9);
  EXPECT_NEAR(std::atan2(e29.y(), e29.x()) * 180 / std::numbers::pi, 360.0 * 9 / 10 + 18 - 360, 1e-9);
}

// run's close training views: 32 per fraction of the orbit radius, between the
// training orbit's azimuths, with the set's intrinsics; none by default of [].
TEST(Camera, CloseViewsPerFractionOfTheOrbitRadius) {
  CameraOptions options;
  options.close_radii = {0.7, 0.5};
  const CameraSet close = close_views(options);
  ASSERT_EQ(close.views.size(), 64u);
  EXPECT_EQ(close.views.front().name, "close_000");
  EXPECT_EQ(close.views.back().name, "close_063");
  EXPECT_EQ(close.intrinsics.width, options.width);
  for (std::size_t i = 0; i < close.views.size(); ++i) {
    EXPECT_NEAR(close.views[i].center_world().norm(), (i < 32 ? 0.7 : 0.5) * 2.5, 1e-9) << i;
  }
  const Eigen::Vector3d c0 = close.views[0].center_world();
  EXPECT_NEAR(std::asin(c0.z() / 1.75) * 180 / std::numbers::pi, -30.0, 1e-9);
  EXPECT_NEAR(std::atan2(c0.y(), c0.x()) * 180 / std::numbers::pi, 360.0 * 0.25 / 8, 1e-9);
  options.close_radii = {};
  EXPECT_TRUE(close_views(options).views.empty());
  for (const double bad : {0.2, 1.0, std::nan("")}) {
    options.close_radii = {0.7, bad};
    try {
      options.validate();
      ADD_FAILURE() << bad << " was accepted";
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("camera.close_radii = [0.7, "), std::string::npos) << e.what();
    }
  }
}

TEST(Camera, ProjectionInvertsRayDirection) {
  const Intrinsics K = make_intrinsics(CameraOptions{});
  const CameraView v = orbit_view(-30, 200, 2.5, "v");
  for (double u : {0.5, 100.25, 255.5})
    for (double w : {0.5, 31.0, 200.75}) {
      const Eigen::Vector3d p = v.center_world() + 1.7 * ray_direction(K, v, u, w);
      const Eigen::Vector3d uvz = project(K, v, p);
      EXPECT_NEAR(uvz.x(), u, 1e-9);
      EXPECT_NEAR(uvz.y(), w, 1e-9);
      EXPECT_GT(uvz.z(), 0.0);
    }
}

TEST(Camera, JsonRoundTripIsExact) {
  testing::ScratchDir dir;
  CameraOptions o;
  o.width = 320;
  o.height = 200;
  o.fov_deg = 37.5;
  const CameraSet a = custom_orbit(o, {-90, 12.5, 90}, even_azimuths(7, 3.0));
  write_cameras_json(dir / "c.json", a);
  const CameraSet b = read_cameras_json(dir / "c.json");
  EXPECT_EQ(b.intrinsics.width, 320);
  EXPECT_EQ(b.intrinsics.fx, a.intrinsics.fx);
  EXPECT_EQ(b.intrinsics.cy, a.intrinsics.cy);
  ASSERT_EQ(b.views.size(), a.views.size());
  for (std::size_t i = 0; i < a.views.size(); ++i) {
    EXPECT_EQ(b.views[i].name, a.views[i].name);
    EXPECT_EQ(b.views[i].R_cam_from_world, a.views[i].R_cam_from_world);
    EXPECT_EQ(b.views[i].t_cam_from_world, a.views[i].t_cam_from_world);
  }
}

TEST(Camera, JsonErrorsNameTheKey) {
  testing::ScratchDir dir;
  const std::string good_view = R"({"name": "a", "R": [[1,0,0],[0,1,0],[0,0,1]], "T": [0,0,2.5]})";
  const std::string head = R"("width": 8, "height": 8, "fx": 8, "fy": 8, "cx": 4, "cy": 4, "near": 0.01, "far": 10)";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"{" + head + R"(, "views": [)" + good_view + R"(], "extra": 1})", "extra: unknown key"},
      {"{" + head + R"(, "views": [{"name": "a", "R": [[1,0,0],[0,1,0],[0,0,1]], "T": [0,0,2.5], "K": 1}]})",
       "views[0].K: unknown key"},
      {"{" + head + R"(, "views": [{"name": "a", "R": [[1,0.1,0],[0,1,0],[0,0,1]], "T": [0,0,2.5]}]})",
       "views[0].R: not a rotation"},
      {"{" + head + R"(, "views": [{"name": "a", "R": [[-1,0,0],[0,1,0],[0,0,1]], "T": [0,0,2.5]}]})",
       "views[0].R: not a rotation"},
      {"{" + head + R"(, "views": []})", "views: is empty"},
      {R"({"width": 8, "views": []})", "missing key 'height'"},
      {"{" + head + R"(, "views": [{"name": "a", "R": [[1,0,0],[0,1,0]], "T": [0,0,2.5]}]})", "views[0].R"},
      {"{ not json", "invalid JSON"},
  };
  for (const auto& [text, expect] : cases) {
    testing::write_text(dir / "c.json", text);
    try {
      (void)read_cameras_json(dir / "c.json");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    }
  }
}

// Found by fuzzing (fuzz_cameras): the message for a non-number dumped the whole
// value, and dump() recursing through a deeply nested array overflowed the stack.
TEST(Camera, JsonDeeplyNestedValueIsAnInputError) {
  testing::ScratchDir dir;
  constexpr std::size_t kDepth = 1000000;
  testing::write_text(dir / "c.json", R"({"width": )" + std::string(kDepth, '[') + std::string(kDepth, ']') + "}");
  try {
    (void)read_cameras_json(dir / "c.json");
    FAIL() << "accepted";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("width: expected an integer, got an array"), std::string::npos) << e.what();
  }
}

// get<int>() wrapped integers outside int silently: 4294967297 read as width 1.
TEST(Camera, JsonIntegerOutOfRangeIsAnError) {
  testing::ScratchDir dir;
  const std::string rest = R"("fx": 8, "fy": 8, "cx": 4, "cy": 4, "near": 0.01, "far": 10,
      "views": [{"name": "a", "R": [[1,0,0],[0,1,0],[0,0,1]], "T": [0,0,2.5]}]})";
  for (const char* width : {"4294967297", "18446744073709551615", "-4294967295"}) {
    testing::write_text(dir / "c.json", std::string(R"({"width": )") + width + R"(, "height": 8, )" + rest);
    try {
      (void)read_cameras_json(dir / "c.json");
      ADD_FAILURE() << "accepted width " << width;
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("width: ") + width + " is out of range"), std::string::npos)
          << e.what();
    }
  }
}

// Hostile sizes: a side over 16384, or views whose images would not fit
// in the allocation limit, get an error naming the file before anything is allocated.
TEST(Camera, JsonHostileSizesAreRefusedBeforeAllocating) {
  testing::ScratchDir dir;
  const std::string view = R"({"name": "a", "R": [[1,0,0],[0,1,0],[0,0,1]], "T": [0,0,2.5]})";
  auto cameras = [&](int side, int views) {
    std::string list;
    for (int i = 0; i < views; ++i) list += (i ? "," : "") + view;
    return R"({"width": )" + std::to_string(side) + R"(, "height": )" + std::to_string(side) +
           R"(, "fx": 8, "fy": 8, "cx": 4, "cy": 4, "near": 0.01, "far": 10, "views": [)" + list + "]}";
  };
  testing::write_text(dir / "big.json", cameras(100000, 1));
  try {
    (void)read_cameras_json(dir / "big.json");
    ADD_FAILURE() << "accepted a 100000x100000 camera";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("width/height: 100000x100000 is outside [1, 16384]"), std::string::npos)
        << e.what();
  }
  // 64 views of 16384² floats are 64 GiB; with a 1 GiB limit that is refused.
  const testing::ScopedEnv limit("HISNEGS_MAX_ALLOC_GB", "1");
  testing::write_text(dir / "many.json", cameras(16384, 64));
  try {
    (void)read_cameras_json(dir / "many.json");
    ADD_FAILURE() << "accepted 64 GiB of images";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("would need 64.00 GiB for 64 float32 images of 16384x16384"),
              std::string::npos)
        << e.what();
  }
  testing::write_text(dir / "fits.json", cameras(64, 64));
  EXPECT_EQ(read_cameras_json(dir / "fits.json").views.size(), 64u);
}

// Keys and names quoted in messages may hold escaped line breaks ("a\nb"): one line still.
TEST(Camera, JsonMessageQuotingAKeyStaysOneLine) {
  testing::ScratchDir dir;
  testing::write_text(dir / "c.json", R"({"wid\nth": 8})");
  try {
    (void)read_cameras_json(dir / "c.json");
    FAIL() << "accepted";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("wid th: unknown key"), std::string::npos) << e.what();
  }
}

// The camera files shipped for the benchmarks (configs/cameras/) read as CONVENTIONS
// cameras.json: the unseen-camera set is non-square with an off-centre principal
// point and f_y != f_x, at several radii.
TEST(Camera, ShippedCameraFilesRead) {
  const CameraSet set = read_cameras_json(std::filesystem::path(HISNEGS_SOURCE_DIR) / "configs" / "cameras" /
                                          "unseen_320x200.json");
  EXPECT_EQ(set.views.size(), 10u);
  EXPECT_EQ(set.intrinsics.width, 320);
  EXPECT_EQ(set.intrinsics.height, 200);
  EXPECT_NE(set.intrinsics.fx, set.intrinsics.fy);
  double closest = 1e9, farthest = 0;
  for (const CameraView& v : set.views) {
    closest = std::min(closest, v.center_world().norm());
    farthest = std::max(farthest, v.center_world().norm());
  }
  EXPECT_LT(closest, 2.5);
  EXPECT_GT(farthest, 3.0);
}

}  // namespace
}  // namespace hisnegs::splat
