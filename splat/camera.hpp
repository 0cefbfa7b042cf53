// SPDX-License-Identifier: Apache-2.0
// Pinhole cameras exactly as CONVENTIONS "Cameras" defines them: intrinsics
// from the FOV, world->camera poses (OpenCV axes), the training (106) and
// evaluation (30) orbits and arbitrary orbits, and cameras.json read/write.
// Knows nothing of what is rendered with them.
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

#include "splat/splat_options.hpp"

namespace hisnegs::splat {

// Shared by every view of a camera set (its largest side: kMaxImageSide, splat_options.hpp).

struct Intrinsics {
  int width = 256, height = 256;   // pixels
  double fx = 0, fy = 0;           // focal lengths, pixels
  double cx = 0, cy = 0;           // principal point, pixels (pixel (c, r) has centre (c + 0.5, r + 0.5))
  double near = 0.01, far = 10.0;  // clipping distances, world units
};

// fx = fy = (W/2) / tan(fov/2), cx = W/2, cy = H/2 (CONVENTIONS defaults).
[[nodiscard]] Intrinsics make_intrinsics(const CameraOptions& options);

// One view: p_cam = R_cam_from_world * p_world + t_cam_from_world (x right, y down, z forward).
struct CameraView {
  std::string name;
  Eigen::Matrix3d R_cam_from_world = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t_cam_from_world = Eigen::Vector3d::Zero();

  // Camera centre C = -Rᵀ T, world units.
  [[nodiscard]] Eigen::Vector3d center_world() const { return -R_cam_from_world.transpose() * t_cam_from_world; }
};

struct CameraSet {
  Intrinsics intrinsics;
  std::vector<CameraView> views;
};

// The orbit pose of CONVENTIONS: C = r (cos e cos φ, cos e sin φ, sin e) looking at the
// origin, z_c = -C/|C|, x_c = normalize(z_c × up) with up = (0,0,1), or (0,1,0) when
// |sin e| > 0.999, y_c = z_c × x_c; R's rows are x_c, y_c, z_c and T = -R C.
[[nodiscard]] CameraView orbit_view(double elevation_deg, double azimuth_deg, double radius, std::string name);

// Training views (report §4.1): r = orbit_radius, rings e = -30, 0, 30, 60 with
// 27, 27, 26, 26 views, φ_j = 360 (j + 0.5 (ring mod 2)) / n. Names train_000..train_105.
[[nodiscard]] CameraSet training_orbit(const CameraOptions& options);
// Evaluation views: rings e = -15, 15, 45, 10 views each, φ_j = 360 j / 10 + 18. Names eval_000..eval_029.
[[nodiscard]] CameraSet evaluation_orbit(const CameraOptions& options);
// Close training views (CameraOptions::close_radii): per fraction f, rings e = -30,
// 0, 30, 60 of 8 views at r = f × orbit_radius, φ_j = 360 (j + 0.25 + 0.5 (ring mod
// 2)) / 8 (between the training orbit's azimuths). Names close_000, ...; the
// intrinsics of `options`.
[[nodiscard]] CameraSet close_views(const CameraOptions& options);
// Every combination of `elevations_deg` × `azimuths_deg` (elevation-major), names view_000...
[[nodiscard]] CameraSet custom_orbit(const CameraOptions& options, const std::vector<double>& elevations_deg,
                                     const std::vector<double>& azimuths_deg);
// `count` views evenly spaced in azimuth (φ_j = 360 j / count + azimuth0_deg) at one elevation.
[[nodiscard]] std::vector<double> even_azimuths(int count, double azimuth0_deg = 0.0);

// Projects a world point: (u, v) in pixels and depth z_c; z_c <= 0 means behind the camera.
[[nodiscard]] Eigen::Vector3d project(const Intrinsics& K, const CameraView& view, const Eigen::Vector3d& p_world);
// Unit direction of the ray through pixel coordinates (u, v): normalize(Rᵀ K⁻¹ (u, v, 1)).
[[nodiscard]] Eigen::Vector3d ray_direction(const Intrinsics& K, const CameraView& view, double u, double v);

// cameras.json (CONVENTIONS "Files"): {"width","height","fx","fy","cx","cy","near","far",
// "views":[{"name","R":[[3],[3],[3]],"T":[3]}]}. Written atomically with full double precision.
// The cameras.json document of `cameras` (CONVENTIONS "cameras.json"), as
// write_cameras_json writes it: doubles in max_digits10, so it reads back bit-exactly.
[[nodiscard]] std::string cameras_json_text(const CameraSet& cameras);

void write_cameras_json(const std::filesystem::path& path, const CameraSet& cameras);
// Throws io::InputError naming the file and key for: invalid JSON, unknown or missing keys,
// wrong types, non-positive sizes/focals, near >= far, R not orthonormal with det +1
// (tolerance 1e-6), non-finite numbers, no views.
[[nodiscard]] CameraSet read_cameras_json(const std::filesystem::path& path);

}  // namespace hisnegs::splat
