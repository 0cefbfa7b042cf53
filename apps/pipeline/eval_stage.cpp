// SPDX-License-Identifier: Apache-2.0
// evaluate_model and the run folder's evaluation stage.
#include "apps/pipeline/eval_stage.hpp"

#include <cstdio>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "apps/pipeline/halo_measure.hpp"
#include "gmf/core/hierarchy.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/psnr.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/stack_file.hpp"
#include "io/png.hpp"
#include "splat/lod.hpp"
#include "splat/render_views.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::apps {
namespace {

using Json = nlohmann::ordered_json;

Json summary_json(const splat::MetricSummary& s) {
  return Json{{"mean", s.mean}, {"std", s.std}, {"min", s.min}, {"max", s.max}};
}

// Per view: metrics, a CSV row, a JSON record and DIR/compare/NNN.png.
struct ViewMeasurements {
  std::vector<double> psnr, mae, ssim, visible;
  std::ostringstream csv;
  Json views = Json::array();
};

void measure_views(const splat::TrainingData& truth, const splat::RenderedViews& r, const std::filesystem::path& dir,
                   ViewMeasurements& m) {
  const int W = truth.intrinsics.width, H = truth.intrinsics.height;
  m.csv.precision(10);
  m.csv << "view,name,psnr,mae,ssim,visible\n";
  for (int i = 0; i < truth.count(); ++i) {
    const splat::ViewMetrics v = splat::image_metrics(r.stack.view(i), truth.image(i), W, H);
    const int visible = r.stats[static_cast<std::size_t>(i)].visible;
    m.psnr.push_back(v.psnr);
    m.mae.push_back(v.mae);
    m.ssim.push_back(v.ssim);
    m.visible.push_back(visible);
    const std::string& name = truth.views[static_cast<std::size_t>(i)].name;
    m.csv << i << "," << name << "," << v.psnr << "," << v.mae << "," << v.ssim << "," << m.visible.back() << "\n";
    m.views.push_back(
        {{"view", i}, {"name", name}, {"psnr", v.psnr}, {"mae", v.mae}, {"ssim", v.ssim}, {"visible", visible}});
    char file[32];
    std::snprintf(file, sizeof file, "%03d.png", i);
    io::write_png(dir / "compare" / file, splat::comparison_image(truth.image(i), r.stack.view(i), W, H));
  }
}

// One MIP mode's figures over every view: whole-image PSNR, the foreground's and
// the background's (splat::foreground_split), and the background's error share.
struct ModeFigures {
  std::vector<double> psnr, psnr_fg, psnr_bg, bg_share;
  Json json() const {
    return Json{{"psnr", summary_json(splat::summarize(psnr))},
                {"psnr_fg", summary_json(splat::summarize(psnr_fg))},
                {"psnr_bg", summary_json(splat::summarize(psnr_bg))},
                {"background_error_share", summary_json(splat::summarize(bg_share))}};
  }
};
ModeFigures mode_figures(const splat::TrainingData& truth, const splat::RenderedViews& r) {
  ModeFigures f;
  for (int i = 0; i < truth.count(); ++i) {
    const splat::ForegroundSplit s = splat::foreground_split(r.stack.view(i), truth.image(i));
    f.psnr.push_back(gmf::psnr(r.stack.view(i), truth.image(i)));
    f.psnr_fg.push_back(s.psnr_fg);
    f.psnr_bg.push_back(s.psnr_bg);
    f.bg_share.push_back(s.background_error_share);
  }
  return f;
}

// The two "eval:" lines: the configured mode's figures, then both modes'.
void say_outcome(const EvalOutcome& outcome, const splat::TrainingData& truth, std::size_t gaussians,
                 const std::string& mode, const std::filesystem::path& dir, const ModeFigures& soft,
                 const ModeFigures& hard, const Progress& progress) {
  const splat::MetricSummary &p = outcome.psnr, &a = outcome.mae, &s = outcome.ssim;
  progress.say("eval: %d views of %dx%d, K %zu, %s MIP: PSNR %.2f ± %.2f dB (min %.2f), MAE %.5f, SSIM %.4f -> %s",
               truth.count(), truth.intrinsics.width, truth.intrinsics.height, gaussians, mode.c_str(), p.mean, p.std,
               p.min, a.mean, s.mean, (dir / "metrics.json").c_str());
  auto mean = [](const std::vector<double>& v) { return splat::summarize(v).mean; };
  progress.say("eval: soft MIP %.2f dB (foreground %.2f dB), hard MIP %.2f dB (foreground %.2f dB, background "
               "%.2f dB, %.0f%% of its error in the background; foreground: truth >= %g)",
               mean(soft.psnr), mean(soft.psnr_fg), mean(hard.psnr), mean(hard.psnr_fg), mean(hard.psnr_bg),
               100 * mean(hard.bg_share), splat::kForegroundLevel);
}

}  // namespace

EvalOutcome evaluate_model(const std::filesystem::path& model, const std::filesystem::path& set,
                           const std::filesystem::path& dir, const EvalConfig& config, splat::Backend backend,
                           const Progress& progress, const std::filesystem::path& stack,
                           const std::optional<splat::LodOptions>& lod) {
  config.get<&AppConfig::splat>().validate();
  const splat::TrainingData truth = splat::load_training_data(set);
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(model.string());
  const splat::SplatSettings settings = splat::SplatSettings::from(config.get<&AppConfig::splat>());
  auto renderer = splat::make_splat_renderer(backend);
  const splat::CameraSet cameras{truth.intrinsics, truth.views};
  const splat::BackgroundFloors floors =
      splat::floors_of(checkpoint.meta, model.string(), config.get<&AppConfig::splat>().background);
  std::optional<gmf::Hierarchy> hierarchy;
  std::vector<std::size_t> drawn;
  if (lod) hierarchy = gmf::hierarchy_of(model, checkpoint);
  const auto render = [&](const splat::SplatSettings& s) {
    if (!hierarchy) return splat::render_views(*renderer, splat::flat_params(checkpoint.mixture), cameras, s, {}, floors);
    drawn.clear();
    return splat::render_views_lod(*renderer, *hierarchy, cameras, s, *lod, floors, &drawn);
  };
  const splat::RenderedViews r = render(settings);
  ViewMeasurements m;
  measure_views(truth, r, dir, m);
  EvalOutcome outcome;
  outcome.views = truth.count();
  outcome.psnr = splat::summarize(m.psnr);
  outcome.mae = splat::summarize(m.mae);
  outcome.ssim = splat::summarize(m.ssim);
  // What a viewer shows (the hard MIP) beside what training optimizes (the soft MIP
  // at β): both, each whole, on the foreground and on the background.
  splat::SplatSettings other = settings;
  other.mode = settings.soft() ? splat::MipMode::kMax : splat::MipMode::kSoftmax;
  const splat::RenderedViews r_other = render(other);
  const ModeFigures mine = mode_figures(truth, r), theirs = mode_figures(truth, r_other);
  const ModeFigures& soft = settings.soft() ? mine : theirs;
  const ModeFigures& hard = settings.soft() ? theirs : mine;
  outcome.soft_psnr = splat::summarize(soft.psnr);
  outcome.hard_psnr = splat::summarize(hard.psnr);
  outcome.hard_psnr_fg = splat::summarize(hard.psnr_fg);
  Json meta;
  meta["model"] = io::printable(model.string(), 500);
  meta["data"] = io::printable(set.string(), 500);
  meta["gaussians"] = checkpoint.mixture.size();
  meta["mode"] = settings.mode == splat::MipMode::kSoftmax ? "soft" : "hard";
  meta["beta"] = settings.beta;
  meta["background"] = floors.none() ? "none" : "the model's floor";
  meta["backend"] = std::string(splat::to_string(backend));
  meta["views"] = truth.count();
  meta["psnr"] = summary_json(outcome.psnr);
  meta["mae"] = summary_json(outcome.mae);
  meta["ssim"] = summary_json(outcome.ssim);
  meta["visible"] = summary_json(splat::summarize(m.visible));
  meta["foreground_level"] = splat::kForegroundLevel;
  meta["modes"] = Json{{"soft", soft.json()}, {"hard", hard.json()}};
  std::optional<gmf::HaloCount> halos;
  if (!stack.empty()) {
    halos = count_model_halos(checkpoint, stack, config.get<&AppConfig::volume>());
    meta["halos"] = Json{{"count", halos->halos}, {"share", halos->share()}, {"noise", halos->noise},
                         {"stack", io::printable(stack.string(), 500)}};
  }
  if (lod) {
    meta["lod"] = Json{{"pixels", lod->pixels}, {"budget", lod->budget}, {"nodes", hierarchy->nodes.size()},
                       {"gaussians_per_view", drawn}};
  }
  meta["per_view"] = m.views;
  const std::string json = meta.dump(2) + "\n", table = m.csv.str();
  io::write_file_atomic(dir / "metrics.csv", table.data(), table.size());
  io::write_file_atomic(dir / "metrics.json", json.data(), json.size());
  say_outcome(outcome, truth, checkpoint.mixture.size(), meta["mode"].get<std::string>(), dir, soft, hard, progress);
  if (halos) {
    progress.say("eval: halos: %s", halo_text(*halos).c_str());
  }
  if (lod && !drawn.empty()) {
    const auto [fewest, most] = std::minmax_element(drawn.begin(), drawn.end());
    progress.say("eval: level of detail at %g px: %zu nodes; the views draw %zu to %zu of the model's %zu Gaussians",
                 lod->pixels, hierarchy->nodes.size(), *fewest, *most, checkpoint.mixture.size());
  }
  return outcome;
}

nlohmann::ordered_json EvalStage::run(const RunRequest& request, const Config& config, bool, const Progress& progress) {
  const std::filesystem::path dir = request.dir / "eval";
  clear_stage_folder(request.dir, kFolder, request.volume);
  // The halos against the stack, when the stack is read whole without trouble.
  const io::StackHeader header =
      io::inspect_stack(request.volume, io::stack_read_options(config.get<&AppConfig::volume>()));
  const double bytes = 4.0 * header.nx * header.ny * static_cast<double>(header.nz);
  if (bytes > kHaloStackBytes) {
    progress.say("eval: halos not counted: the stack is %s as float32 (counted up to %s)", io::gib_text(bytes).c_str(),
                 io::gib_text(kHaloStackBytes).c_str());
  }
  evaluate_model(request.dir / "train" / "final.ply", request.dir / "gt" / "eval", dir, config, request.backend,
                 progress, bytes <= kHaloStackBytes ? request.volume : std::filesystem::path());
  return nullptr;
}

}  // namespace hisnegs::apps
