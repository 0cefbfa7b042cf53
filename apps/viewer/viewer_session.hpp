// SPDX-License-Identifier: Apache-2.0
// What `hisnegs view` serves: the viewer page of a checkpoint file as it is now
// (re-read when the file changes, so a re-fitted model shows on reload; a bad file
// gives an error page, not a dead server) and, with a volume, the CPU ray-marched
// MIP of any camera with the PSNR of the model's CPU hard MIP against it.
#pragma once

#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "apps/viewer/viewer_page.hpp"
#include "apps/viewer/viewer_server.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/load_volume.hpp"
#include "splat/camera.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {
class RayMarcher;
class SplatRenderer;
}  // namespace hisnegs::splat

namespace hisnegs::apps {

struct ViewerSessionOptions {
  std::filesystem::path model;  // checkpoint (.ply or .hgs)
  splat::CameraSet cameras;     // the views #view=N shows; their intrinsics size /truth
  ViewerPageSettings page;      // cutoff and low-pass (the CPU renderer's)
  std::optional<std::filesystem::path> volume;  // TIFF stack for /truth
  io::VolumeOptions volume_options;
  splat::RaymarchOptions raymarch;
  bool background = true;  // draw the background floor the model records (splat.background)
};

// The ray-marched MIP of one camera and how the model compares with it.
struct ViewerTruth {
  std::vector<float> image;  // height x width, row-major, [0, 1]
  double psnr_db = 0;        // the model's CPU hard MIP against `image` (CONVENTIONS Metrics); +inf for MSE 0
  double mse = 0;            // its mean squared error
  float truth_max = 0;       // the brightest pixel of `image` (0: the volume is empty in this view)
};

class ViewerSession {
 public:
  // Loads and checks the volume when given (io::InputError naming it, e.g. a stack
  // that is not the model's world box). The model is read lazily by page().
  explicit ViewerSession(ViewerSessionOptions options);
  ~ViewerSession();
  ViewerSession(const ViewerSession&) = delete;
  ViewerSession& operator=(const ViewerSession&) = delete;

  // The page of the model file as it is now: re-read when its size or modification
  // time changed since the last call. Throws io::InputError for a bad file.
  [[nodiscard]] std::string page();
  // The model of the last successful page() (loads it if there was none).
  [[nodiscard]] gmf::Checkpoint model();

  [[nodiscard]] bool has_volume() const { return static_cast<bool>(marcher_); }
  // Renders `view` with the cameras' intrinsics, against the model file as it is now
  // (re-read like page(); a broken file throws io::InputError here too, never an
  // answer from the last good model). Requires has_volume().
  [[nodiscard]] ViewerTruth truth(const splat::CameraView& view);

  // The routes of serve_viewer: "/" answers the page, or a 500 error page naming the
  // problem (and one stderr line "view: error: ..."); "/truth?R=r00,...,r22&T=t0,t1,t2"
  // (when a volume was given) answers W x H little-endian float32 with the headers
  // X-Hisnegs-Psnr (dB, or "Infinity" for MSE 0), X-Hisnegs-Mse and
  // X-Hisnegs-Truth-Max; 400 for a malformed camera; 500 naming the problem when the
  // model file is broken.
  [[nodiscard]] ViewerRoutes routes();

 private:
  struct FileStamp {
    std::uintmax_t size = 0;
    std::filesystem::file_time_type time{};
    friend bool operator==(const FileStamp&, const FileStamp&) = default;
  };
  void reload_if_changed();  // with mutex_ held

  ViewerSessionOptions options_;
  std::mutex mutex_;
  std::optional<FileStamp> stamp_;
  std::shared_ptr<const gmf::Checkpoint> checkpoint_;
  splat::BackgroundFloors floors_;  // of checkpoint_, or none
  std::string page_;
  io::LoadedVolume volume_;
  std::unique_ptr<splat::RayMarcher> marcher_;
  std::unique_ptr<splat::SplatRenderer> renderer_;
};

// The camera of a /truth query: R (9 numbers, row-major) and T (3), each field given
// once, comma-separated finite decimal numbers (no empty item, no hex), R
// orthonormal to 1e-3 with det +1. Throws io::InputError naming the field.
[[nodiscard]] splat::CameraView camera_from_query(const ViewerQuery& query);

}  // namespace hisnegs::apps
