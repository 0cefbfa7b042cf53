// `hisnegs eval --model m.ply --data GTDIR -o DIR`: renders the evaluation views
// (GTDIR/eval, or GTDIR itself when it holds cameras.json) and measures each
// against its ground truth: DIR/metrics.json, metrics.csv, compare/NNN.png.
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "gmf/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/png.hpp"
#include "splat/metrics.hpp"
#include "splat/render_views.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::apps {

EvalOutcome evaluate_model(const std::filesystem::path& model, const std::filesystem::path& set,
                           const std::filesystem::path& dir, const AppConfig& config, splat::Backend backend,
                           bool quiet) {
  config.splat.validate();
  const splat::TrainingData truth = splat::load_training_data(set);
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(model.string());
  const splat::SplatSettings settings = splat::SplatSettings::from(config.splat);
  auto renderer = splat::make_splat_renderer(backend);
  const splat::CameraSet cameras{truth.intrinsics, truth.views};
  const splat::RenderedViews r = splat::render_views(*renderer, splat::flat_params(checkpoint.mixture), cameras, settings);
  const int W = truth.intrinsics.width, H = truth.intrinsics.height;
  std::vector<double> psnr, mae, ssim, visible;
  std::ostringstream csv;
  csv.precision(10);
  csv << "view,name,psnr,mae,ssim,visible\n";
  nlohmann::ordered_json views = nlohmann::json::array();
  for (int i = 0; i < truth.count(); ++i) {
    const splat::ViewMetrics m = splat::image_metrics(r.stack.view(i), truth.image(i), W, H);
    psnr.push_back(m.psnr);
    mae.push_back(m.mae);
    ssim.push_back(m.ssim);
    visible.push_back(r.stats[static_cast<std::size_t>(i)].visible);
    const std::string& name = truth.views[static_cast<std::size_t>(i)].name;
    csv << i << "," << name << "," << m.psnr << "," << m.mae << "," << m.ssim << "," << visible.back() << "\n";
    views.push_back({{"view", i}, {"name", name}, {"psnr", m.psnr}, {"mae", m.mae}, {"ssim", m.ssim},
                     {"visible", r.stats[static_cast<std::size_t>(i)].visible}});
    char file[32];
    std::snprintf(file, sizeof file, "%03d.png", i);
    io::write_png(dir / "compare" / file, splat::comparison_image(truth.image(i), r.stack.view(i), W, H));
  }
  const EvalOutcome outcome{truth.count(), splat::summarize(psnr), splat::summarize(mae), splat::summarize(ssim)};
  auto summary = [](const splat::MetricSummary& s) {
    return nlohmann::ordered_json{{"mean", s.mean}, {"std", s.std}, {"min", s.min}, {"max", s.max}};
  };
  nlohmann::ordered_json meta;
  meta["model"] = io::printable(model.string(), 500);
  meta["data"] = io::printable(set.string(), 500);
  meta["gaussians"] = checkpoint.mixture.size();
  meta["mode"] = settings.mode == splat::MipMode::kSoft ? "soft" : "hard";
  meta["beta"] = settings.beta;
  meta["backend"] = std::string(splat::to_string(backend));
  meta["views"] = truth.count();
  meta["psnr"] = summary(outcome.psnr);
  meta["mae"] = summary(outcome.mae);
  meta["ssim"] = summary(outcome.ssim);
  meta["visible"] = summary(splat::summarize(visible));
  meta["per_view"] = views;
  const std::string json = meta.dump(2) + "\n", table = csv.str();
  io::write_file_atomic(dir / "metrics.csv", table.data(), table.size());
  io::write_file_atomic(dir / "metrics.json", json.data(), json.size());
  if (!quiet) {
    const splat::MetricSummary &p = outcome.psnr, &a = outcome.mae, &s = outcome.ssim;
    std::printf("eval: %d views of %dx%d, K %zu, %s MIP: PSNR %.2f ± %.2f dB (min %.2f), MAE %.5f, SSIM %.4f -> %s\n",
                truth.count(), W, H, checkpoint.mixture.size(), meta["mode"].get<std::string>().c_str(), p.mean,
                p.std, p.min, a.mean, s.mean, (dir / "metrics.json").c_str());
  }
  return outcome;
}

void add_eval_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("eval", "measure a model on the evaluation views: PSNR, MAE, SSIM per view (metrics.json/csv)");
  struct Args {
    std::string model, data, out, mode, backend = "auto";
    std::optional<double> beta;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("--model", args->model, "checkpoint (.ply)")->required();
  cmd->add_option("--data", args->data, "ground-truth folder of `hisnegs gt` (uses GTDIR/eval)")->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--mode", args->mode, "soft | hard (default splat.mode)");
  cmd->add_option("--beta", args->beta, "soft-MIP beta (default splat.beta)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (!args->mode.empty()) io::set_enum_field(config.splat, "mode", args->mode, "--mode");
    if (args->beta) config.splat.beta = *args->beta;
    config.splat.validate();
    const std::filesystem::path data = args->data;
    const std::filesystem::path set = std::filesystem::exists(data / "eval" / "cameras.json") ? data / "eval" : data;
    evaluate_model(args->model, set, args->out, config, splat::resolve_backend(splat::parse_backend_request(args->backend)),
                   global.quiet);
  });
}

}  // namespace hisnegs::apps
