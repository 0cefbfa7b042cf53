// SPDX-License-Identifier: Apache-2.0
// `hisnegs view`'s model and volume: the page rebuilt when the checkpoint file
// changes, and the ground truth of any camera rendered on request (CPU).
#include "apps/viewer/viewer_session.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string_view>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "gmf/core/psnr.hpp"
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

// One decimal number as JavaScript's String(Number) writes it: digits, an optional
// fraction and exponent (no hex, no inf/nan, no leading '+'); a value that underflows
// to a subnormal or 0 is that value; one that overflows is not finite.
std::optional<double> decimal_number(std::string_view text) {
  double v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v, std::chars_format::general);
  if (end != text.data() + text.size() || text.empty()) return std::nullopt;
  if (ec == std::errc::result_out_of_range) {
    const double approx = std::strtod(std::string(text).c_str(), nullptr);  // ±HUGE_VAL or the underflowed value
    return std::isfinite(approx) ? std::optional<double>(approx) : std::nullopt;
  }
  if (ec != std::errc() || !std::isfinite(v)) return std::nullopt;
  return v;
}

// Comma-separated finite numbers of query field `name` (given once), exactly
// `count` of them, no empty item.
std::vector<double> numbers(const ViewerQuery& query, const std::string& name, std::size_t count) {
  const auto it = query.find(name);
  if (it == query.end()) throw io::InputError("/truth: missing field " + name);
  if (query.count(name) > 1) {
    throw io::InputError("/truth: field " + name + " is given " + std::to_string(query.count(name)) +
                         " times; give it once");
  }
  const std::string& text = it->second;
  std::vector<double> out;
  for (std::size_t start = 0;;) {
    const std::size_t comma = text.find(',', start);
    const std::string_view item =
        std::string_view(text).substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    const std::optional<double> v = decimal_number(item);
    if (!v) {
      throw io::InputError("/truth: field " + name + " = '" + io::printable(text, 200) + "': '" +
                           io::printable(item, 40) + "' is not a finite decimal number");
    }
    out.push_back(*v);
    if (comma == std::string::npos) break;
    start = comma + 1;
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
  const double det = view.R_cam_from_world.determinant();
  if (off > 1e-3) {
    throw io::InputError("/truth: field R is not a rotation: not orthonormal (largest |R Rᵀ − I| = " +
                         io::number_text(off) + ", at most 0.001)");
  }
  if (det < 0) {
    throw io::InputError("/truth: field R is not a rotation: a reflection (det R = " + io::number_text(det) +
                         ", a rotation has +1)");
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
  settings.floor = splat::floors_of(checkpoint->meta, path.string(), options_.background);
  settings.truth = has_volume();
  page_ = viewer_html(checkpoint->mixture, options_.cameras, settings);
  floors_ = std::move(settings.floor);
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
  reload_if_changed();  // the model file as it is now, as "/" shows it: a broken file is an error here too
  const splat::Intrinsics& K = options_.cameras.intrinsics;
  ViewerTruth out;
  out.image.assign(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  marcher_->render(K, view, out.image);
  splat::SplatOptions hard;
  hard.mode = splat::MipMode::kMax;
  hard.mahalanobis_cutoff = options_.page.cutoff;
  hard.low_pass = options_.page.low_pass;
  std::vector<float> model(out.image.size(), 0.0f);
  splat::SplatSettings settings = splat::SplatSettings::from(hard);
  const std::vector<float> floor = floors_(K, view);  // as the page draws it
  settings.floor = floor;
  renderer_->forward(gmf::flat_params(checkpoint_->mixture), K, view, settings, model);
  out.psnr_db = splat::image_metrics(model, out.image, K.width, K.height).psnr;
  out.mse = gmf::mean_squared_error(model, out.image);
  out.truth_max = *std::max_element(out.image.begin(), out.image.end());
  return out;
}

ViewerRoutes ViewerSession::routes() {
  ViewerRoutes routes;
  routes.page = [this] {
    ViewerReply reply;
    try {
      reply.body = page();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "view: error: %s\n", io::printable(e.what()).c_str());
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
      // PSNR in dB, or "Infinity" (what JavaScript's parseFloat reads) where the
      // model's MIP equals the volume's (MSE 0: e.g. both blank); the MSE itself and
      // the volume MIP's brightest pixel (0: the volume is empty in this view).
      char psnr[32], mse[32], peak[32];
      if (std::isfinite(t.psnr_db)) {
        std::snprintf(psnr, sizeof psnr, "%.4f", t.psnr_db);
      } else {
        std::snprintf(psnr, sizeof psnr, "Infinity");
      }
      std::snprintf(mse, sizeof mse, "%.6g", t.mse);
      std::snprintf(peak, sizeof peak, "%.6g", static_cast<double>(t.truth_max));
      reply.headers.emplace_back("X-Hisnegs-Psnr", psnr);
      reply.headers.emplace_back("X-Hisnegs-Mse", mse);
      reply.headers.emplace_back("X-Hisnegs-Truth-Max", peak);
      return reply;
    };
  }
  return routes;
}

}  // namespace hisnegs::apps
