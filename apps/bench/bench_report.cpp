// SPDX-License-Identifier: Apache-2.0
// `hisnegs bench report -o DIR`: the report's experiment tables measured in one run
// on this machine and back end: Table 7 (speed against resolution, with the ray
// marcher), 9 (speed against K), 10 (360 degree orbit frame times), 11 (soft-MIP
// against beta) and 12 (memory), as DIR/report.md and DIR/tableN.csv.
//
// Timing: each case renders frames cycling through the evaluation views after a
// warm-up, until it has `max_frames` frames or has spent `seconds_per_case` (at
// least `min_frames` frames); the figure is the median frame. Wall clock, one
// frame at a time, as a viewer would render them.
#include "apps/bench/bench_report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/psnr.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/load_volume.hpp"
#include "io/timer.hpp"
#include "splat/ground_truth.hpp"
#include "splat/metrics.hpp"
#include "splat/raymarch.hpp"
#include "splat/render_views.hpp"
#include "splat/synthetic_mixture.hpp"

namespace hisnegs::apps::bench {
namespace {

namespace fs = std::filesystem;

struct Timed {
  std::vector<double> seconds;  // per measured frame
  double visible = 0;           // mean visible Gaussians
};

class Timer {
 public:
  explicit Timer(const BenchReportRequest& r) : r_(r) {}

  // Splatting frames of `params` through `cameras` (cycled).
  Timed splat(splat::SplatRenderer& renderer, std::span<const float> params, const splat::CameraSet& cameras,
              const splat::SplatSettings& settings) const {
    const splat::Intrinsics& K = cameras.intrinsics;
    std::vector<float> image(static_cast<std::size_t>(K.width) * K.height);
    const std::size_t n = cameras.views.size();
    for (std::size_t i = 0; i < 3; ++i) renderer.forward(params, K, cameras.views[i % n], settings, image);
    Timed t;
    io::Stopwatch budget;
    for (std::size_t i = 0; static_cast<int>(i) < r_.max_frames; ++i) {
      if (static_cast<int>(i) >= r_.min_frames && budget.elapsed() > r_.seconds_per_case) break;
      io::Stopwatch watch;
      renderer.forward(params, K, cameras.views[i % n], settings, image);
      t.seconds.push_back(watch.elapsed());
      t.visible += renderer.stats().visible;
    }
    t.visible /= static_cast<double>(t.seconds.size());
    return t;
  }

  // Ray-marched ground-truth MIPs of the views, one at a time.
  Timed raymarch(const io::LoadedVolume& volume, const splat::CameraSet& cameras, splat::Backend backend) const {
    Timed t;
    io::Stopwatch budget;
    const std::size_t n = cameras.views.size();
    for (std::size_t i = 0; static_cast<int>(i) < r_.max_frames; ++i) {
      if (static_cast<int>(i) >= r_.min_frames && budget.elapsed() > r_.seconds_per_case) break;
      const splat::CameraSet one{cameras.intrinsics, {cameras.views[i % n]}};
      const splat::MipStack s =
          splat::render_ground_truth(volume.volume, volume.frame, one, splat::RaymarchOptions{}, backend);
      t.seconds.push_back(s.seconds_per_view.at(0));
    }
    return t;
  }

 private:
  const BenchReportRequest& r_;
};

std::string ms(double seconds) { return strf("%.2f", 1e3 * seconds); }
std::string fps(double seconds) { return seconds > 0 ? strf("%.1f", 1.0 / seconds) : std::string("-"); }

splat::CameraSet eval_views(int size) {
  splat::CameraOptions co;
  co.width = co.height = size;
  return splat::evaluation_orbit(co);
}

void write_table(const fs::path& dir, const std::string& name, const Table& t) {
  const std::string csv = t.csv();
  io::write_file_atomic(dir / (name + ".csv"), csv.data(), csv.size());
}

void check_request(const BenchReportRequest& r) {
  if (r.sizes.empty() || r.gaussians.empty() || r.betas.empty()) {
    throw io::InputError("bench report: --sizes, --gaussians and --betas need at least one value each");
  }
  if (r.min_frames < 1 || r.max_frames < r.min_frames) {
    throw io::InputError("bench report: need 1 <= --min-frames <= --max-frames");
  }
  if (r.orbit_frames < 1) throw io::InputError("bench report: --orbit-frames must be at least 1");
}

// What every table measures: the model, the volume, the renderer and the two MIP settings.
struct Bench {
  const BenchReportRequest& r;
  const Progress& progress;
  Timer timer;
  io::LoadedVolume volume;
  std::unique_ptr<splat::SplatRenderer> renderer;
  gmf::GaussianMixture model;
  std::string model_name;
  splat::SplatSettings soft, hard;
  [[nodiscard]] std::span<const float> params() const { return splat::flat_params(model); }
  void say(const std::string& line) const { progress.say("bench report: %s", line.c_str()); }
};

// The checkpoint of the request, or a synthetic Table 3-shaped mixture.
void load_model(Bench& b) {
  if (b.r.model.empty()) {
    splat::SyntheticMixtureOptions o;
    o.gaussians = b.r.model_gaussians;
    b.model = splat::make_synthetic_mixture(o);
    b.model_name = strf("synthetic Table 3-shaped mixture, K = %zu", b.model.size());
  } else {
    b.model = gmf::load_checkpoint(b.r.model.string()).mixture;
    b.model_name = io::printable(b.r.model.string(), 200) + strf(", K = %zu", b.model.size());
  }
}

std::string header_section(const Bench& b) {
  const BenchReportRequest& r = b.r;
  std::string md = "# hisnegs bench report\n\n";
  md += "Machine: " + machine_description() + ".  \n";
  md += "Back end: " + std::string(splat::to_string(r.backend)) + " (splatting and ray marching).  \n";
  md += "Model: " + b.model_name + ".  \n";
  md += strf("Volume (ray marcher, Table 12): %s, %dx%dx%d.  \n",
             io::printable(r.volume_label.empty() ? r.volume.string() : r.volume_label, 200).c_str(),
             b.volume.volume.nx, b.volume.volume.ny, b.volume.volume.nz);
  md += strf(
      "Timing: median wall time per frame over up to %d frames (at least %d, about %.3g s per case) after 3 "
      "warm-up frames, cycling through the 30 evaluation views; soft-MIP beta 50 unless stated.\n\n",
      r.max_frames, r.min_frames, r.seconds_per_case);
  return md;
}

// Table 7: against resolution, with the ray marcher (exact mode, CONVENTIONS).
std::string table7_resolution(const Bench& b) {
  Table t7{{"resolution", "soft-MIP ms", "soft FPS", "hard MIP ms", "hard FPS", "ray-march ms", "ray-march FPS",
            "speedup (soft)", "speedup (hard)"},
           {}};
  for (int size : b.r.sizes) {
    const splat::CameraSet views = eval_views(size);
    const double s = median(b.timer.splat(*b.renderer, b.params(), views, b.soft).seconds);
    const double h = median(b.timer.splat(*b.renderer, b.params(), views, b.hard).seconds);
    const double rm = median(b.timer.raymarch(b.volume, views, b.r.backend).seconds);
    t7.add({strf("%d^2", size), ms(s), fps(s), ms(h), fps(h), ms(rm), fps(rm), strf("%.1fx", rm / s),
            strf("%.1fx", rm / h)});
    b.say(strf("Table 7: %d^2: soft %.2f ms, hard %.2f ms, ray march %.1f ms", size, 1e3 * s, 1e3 * h, 1e3 * rm));
  }
  write_table(b.r.dir, "table7", t7);
  return "## Table 7: rendering speed against resolution\n\n" + t7.markdown() + "\n";
}

// Table 9: against K at 256^2 (synthetic mixtures: a run has no checkpoints of other sizes).
std::string table9_gaussians(const Bench& b) {
  Table t9{
      {"K", "soft-MIP ms", "soft FPS", "hard MIP ms", "hard FPS", "visible K (mean)", "real time (soft >= 30 FPS)?"},
      {}};
  const splat::CameraSet views256 = eval_views(256);
  for (int K : b.r.gaussians) {
    splat::SyntheticMixtureOptions o;
    o.gaussians = K;
    const gmf::GaussianMixture mixture = splat::make_synthetic_mixture(o);
    const std::span<const float> p = splat::flat_params(mixture);
    const Timed s = b.timer.splat(*b.renderer, p, views256, b.soft);
    const double h = median(b.timer.splat(*b.renderer, p, views256, b.hard).seconds);
    const double sm = median(s.seconds);
    t9.add({std::to_string(K), ms(sm), fps(sm), ms(h), fps(h), strf("%.0f", s.visible), sm < 1.0 / 30 ? "yes" : "no"});
    b.say(strf("Table 9: K %d: soft %.2f ms, hard %.2f ms", K, 1e3 * sm, 1e3 * h));
  }
  write_table(b.r.dir, "table9", t9);
  return "## Table 9: rendering speed against K (256^2, synthetic Table 3-shaped mixtures)\n\n" + t9.markdown() + "\n";
}

// Table 10: a 360 degree orbit at elevation 0, every frame timed.
std::string table10_orbit(const Bench& b) {
  splat::CameraOptions co;
  const splat::CameraSet orbit = splat::turntable(co, b.r.orbit_frames, 0.0);
  std::vector<float> image(static_cast<std::size_t>(co.width) * co.height);
  for (int i = 0; i < 3; ++i) b.renderer->forward(b.params(), orbit.intrinsics, orbit.views[0], b.soft, image);
  std::vector<double> seconds;
  for (const splat::CameraView& view : orbit.views) {
    io::Stopwatch watch;
    b.renderer->forward(b.params(), orbit.intrinsics, view, b.soft, image);
    seconds.push_back(watch.elapsed());
  }
  const Table t10 = frame_time_table(seconds);
  write_table(b.r.dir, "table10", t10);
  b.say(strf("Table 10: %d orbit frames, median %.2f ms", b.r.orbit_frames, 1e3 * median(seconds)));
  return strf("## Table 10: 360 degree orbit (%d frames, elevation 0, 256^2, soft-MIP, the model)\n\n",
              b.r.orbit_frames) +
         t10.markdown() + "\n";
}

// Table 11: soft-MIP against beta, images against beta = 1000 and against hard MIP.
std::string table11_beta(const Bench& b) {
  const splat::CameraSet views = eval_views(256);
  const int n = std::min<int>(b.r.quality_views, static_cast<int>(views.views.size()));
  const splat::CameraSet subset{views.intrinsics, {views.views.begin(), views.views.begin() + n}};
  splat::SplatSettings reference = b.soft;
  reference.beta = 1000.0f;
  const splat::MipStack ref = splat::render_views(*b.renderer, b.params(), subset, reference).stack;
  const splat::MipStack max = splat::render_views(*b.renderer, b.params(), subset, b.hard).stack;
  Table t11{{"beta", "PSNR vs beta 1000 (dB)", "MAE", "max error", "PSNR vs hard MIP (dB)", "soft-MIP ms"}, {}};
  for (float beta : b.r.betas) {
    splat::SplatSettings s = b.soft;
    s.beta = beta;
    const splat::MipStack img = splat::render_views(*b.renderer, b.params(), subset, s).stack;
    double mae = 0, max_err = 0;
    for (std::size_t i = 0; i < img.pixels.size(); ++i) {
      const double d = std::abs(static_cast<double>(img.pixels[i]) - ref.pixels[i]);
      mae += d;
      max_err = std::max(max_err, d);
    }
    mae /= static_cast<double>(img.pixels.size());
    const double p_ref = gmf::psnr(img.pixels, ref.pixels);
    const double p_hard = gmf::psnr(img.pixels, max.pixels);
    const double t = median(b.timer.splat(*b.renderer, b.params(), views, s).seconds);
    t11.add(
        {strf("%g", beta), strf("%.2f", p_ref), strf("%.3g", mae), strf("%.3g", max_err), strf("%.2f", p_hard), ms(t)});
    b.say(strf("Table 11: beta %g: %.2f dB against beta 1000", beta, p_ref));
  }
  write_table(b.r.dir, "table11", t11);
  return strf("## Table 11: soft-MIP against beta (256^2, %d evaluation views, the model)\n\n", n) + t11.markdown() +
         "\nPSNR and errors pool all pixels of the views; the time column is the soft-MIP frame time at that beta.\n\n";
}

// Table 12: memory of the volume against the model.
std::string table12_memory(const Bench& b) {
  MemoryInputs mem;
  mem.shape_xyz = {b.volume.volume.nx, b.volume.volume.ny, b.volume.volume.nz};
  mem.gaussians = b.model.size();
  if (!b.r.model.empty())
    mem.checkpoint_file = std::pair{b.r.model.filename().string(), file_bytes(b.r.model.string())};
  const Table t12 = memory_table(mem);
  write_table(b.r.dir, "table12", t12);
  return "## Table 12: memory (the volume against the model)\n\n" + t12.markdown() + "\n";
}

}  // namespace

void write_bench_report(const BenchReportRequest& r, const Progress& progress) {
  check_request(r);
  io::Stopwatch total;
  Bench b{
      r,  progress, Timer(r), io::load_volume(r.volume, io::VolumeOptions{}), splat::make_splat_renderer(r.backend), {},
      {}, {},       {}};
  load_model(b);
  b.soft.mode = splat::MipMode::kSoftmax;
  b.soft.beta = 50.0f;
  b.hard.mode = splat::MipMode::kMax;
  std::string md = header_section(b);
  md += table7_resolution(b);
  md += table9_gaussians(b);
  md += table10_orbit(b);
  md += table11_beta(b);
  md += table12_memory(b);
  md += strf("Measured in %s.\n", format_seconds(total.elapsed()).c_str());
  io::write_file_atomic(r.dir / "report.md", md.data(), md.size());
  b.say("wrote " + (r.dir / "report.md").string() + " and table7/9/10/11/12.csv (" + format_seconds(total.elapsed()) +
        ")");
}

}  // namespace hisnegs::apps::bench
