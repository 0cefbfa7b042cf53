// SPDX-License-Identifier: Apache-2.0
// `hisnegs view`'s model and volume: the page rebuilt when the checkpoint file
// changes, and the ground truth of any camera rendered on request (CPU).
#include "apps/viewer/viewer_session.hpp"

#include <Eigen/LU>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "io/error.hpp"
#include "splat/metrics.hpp"
#include "splat/raymarch.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::apps {
namespace {

std::string html_escaped(const std::string& text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '&': out += "&amp;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string error_page(const std::string& message) {
  return "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>hisnegs view: error</title></head>"
         "<body style=\"font: 14px sans-serif; margin: 2em\"><h1>hisnegs view cannot show this model</h1>"
         "<pre id=\"error\" style=\"color: #b00; white-space: pre-wrap\">" +
         html_escaped(message) +
         "</pre><p>The server keeps running: fix or replace the file, then reload this page.</p></body></html>";
}

// Comma-separated finite numbers of query field `name`, exactly `count` of them.
std::vector<double> numbers(const ViewerQuery& query, const std::string& name, std::size_t count) {
  const auto it = query.find(name);
  if (it == query.end()) throw io::InputError("/truth: missing field " + name);
  std::vector<double> out;
  std::stringstream in(it->second);
  for (std::string item; std::getline(in, item, ',');) {
    std::size_t used = 0;
    double v = 0;
    try {
      v = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != item.size() || !std::isfinite(v)) {
      throw io::InputError("/truth: field " + name + " = '" + it->second + "': '" + item + "' is not a finite number");
    }
    out.push_back(v);
  }
  if (out.size() != count) {
    throw io::InputError("/truth: field " + name + " has " + std::to_string(out.size()) + " numbers, expected " +
                         std::to_string(count));
  }
  return out;
}

}  // namespace

splat::CameraView camera_from_query(const ViewerQuery& query) {
  const std::vector<double> r = numbers(query, "R", 9), t = numbers(query, "T", 3);
  splat::CameraView view;
  view.name = "viewer";
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) view.R_cam_from_world(i, j) = r[3 * i + j];
    view.t_cam_from_world(i) = t[i];
  }
  const double off = (view.R_cam_from_world * view.R_cam_from_world.transpose() - Eigen::Matrix3d::Identity())
                         .cwiseAbs()
                         .maxCoeff();
  if (off > 1e-3 || view.R_cam_from_world.determinant() < 0) {
    throw io::InputError("/truth: field R is not a rotation (|R Rᵀ − I| = " + std::to_string(off) + ")");
  }
  return view;
}

ViewerSession::ViewerSession(ViewerSessionOptions options) : options_(std::move(options)) {
  if (options_.cameras.views.empty()) throw std::invalid_argument("viewer: the camera set has no views");
  if (options_.volume) {
    volume_ = io::load_volume(*options_.volume, options_.volume_options);
    marcher_ = std::make_unique<splat::RayMarcher>(volume_.volume, volume_.frame, options_.raymarch);
    renderer_ = splat::make_splat_renderer(splat::Backend::kCpu);
  }
}

ViewerSession::~ViewerSession() = default;

void ViewerSession::reload_if_changed() {
  const std::filesystem::path& path = options_.model;
  std::error_code ec;
  FileStamp now;
  now.size = std::filesystem::file_size(path, ec);
  if (!ec) now.time = std::filesystem::last_write_time(path, ec);
  if (!ec && stamp_ && *stamp_ == now && checkpoint_) return;
  auto checkpoint = std::make_shared<const gmf::Checkpoint>(gmf::load_checkpoint(path));
  if (options_.volume) gmf::require_same_world_box(checkpoint->meta, volume_.frame, options_.volume->string());
  ViewerPageSettings settings = options_.page;
  settings.um_per_world = um_per_world(checkpoint->meta);
  settings.truth = has_volume();
  page_ = viewer_html(checkpoint->mixture, options_.cameras, settings);
  checkpoint_ = std::move(checkpoint);
  stamp_ = ec ? std::nullopt : std::optional<FileStamp>(now);
}

std::string ViewerSession::page() {
  std::lock_guard lock(mutex_);
  reload_if_changed();
  return page_;
}

gmf::Checkpoint ViewerSession::model() {
  std::lock_guard lock(mutex_);
  if (!checkpoint_) reload_if_changed();
  return *checkpoint_;
}

ViewerTruth ViewerSession::truth(const splat::CameraView& view) {
  if (!has_volume()) throw std::logic_error("ViewerSession::truth without a volume");
  std::lock_guard lock(mutex_);
  if (!checkpoint_) reload_if_changed();
  const splat::Intrinsics& K = options_.cameras.intrinsics;
  ViewerTruth out;
  out.image.assign(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  marcher_->render(K, view, out.image);
  splat::SplatOptions hard;
  hard.mode = splat::MipMode::kHard;
  hard.mahalanobis_cutoff = options_.page.cutoff;
  hard.low_pass = options_.page.low_pass;
  std::vector<float> model(out.image.size(), 0.0f);
  renderer_->forward(gmf::flat_params(checkpoint_->mixture), K, view, splat::SplatSettings::from(hard), model);
  out.psnr_db = splat::image_metrics(model, out.image, K.width, K.height).psnr;
  return out;
}

ViewerRoutes ViewerSession::routes() {
  ViewerRoutes routes;
  routes.page = [this] {
    ViewerReply reply;
    try {
      reply.body = page();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "view: error: %s\n", e.what());
      reply.status = 500;
      reply.body = error_page(e.what());
    }
    return reply;
  };
  if (has_volume()) {
    routes.truth = [this](const ViewerQuery& query) {
      ViewerReply reply;
      splat::CameraView view;
      try {
        view = camera_from_query(query);
      } catch (const io::InputError& e) {
        reply.status = 400;
        reply.content_type = "text/plain; charset=utf-8";
        reply.body = std::string(e.what()) + "\n";
        return reply;
      }
      const ViewerTruth t = truth(view);
      reply.content_type = "application/octet-stream";
      reply.body.assign(reinterpret_cast<const char*>(t.image.data()), t.image.size() * sizeof(float));
      char psnr[32];
      std::snprintf(psnr, sizeof psnr, "%.4f", t.psnr_db);
      reply.headers.emplace_back("X-Hisnegs-Psnr", psnr);
      return reply;
    };
  }
  return routes;
}

}  // namespace hisnegs::apps
