// SPDX-License-Identifier: Apache-2.0
// write_run_report: DIR/report.md of `hisnegs run` from the run folder's files.
#include "apps/pipeline/run_report.hpp"

#include <chrono>
#include <cstdio>
#include <ctime>
#include <fstream>

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;

Json read_json(const fs::path& path) {
  try {
    return Json::parse(io::read_file(path));
  } catch (const Json::exception& e) {
    io::fail_input(path, std::string("invalid JSON: ") + e.what());
  }
}

// The last data line of train/log.csv split at commas (empty if there is none).
std::vector<std::string> last_log_row(const fs::path& path) {
  std::ifstream in(path);
  std::string line, last;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    if (!line.empty()) last = line;
  }
  std::vector<std::string> cells;
  std::size_t start = 0;
  while (!last.empty()) {
    const auto comma = last.find(',', start);
    cells.push_back(last.substr(start, comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return cells;
}

std::string now_utc() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%d %H:%M UTC", std::gmtime(&t));
  return text;
}

const char* stage_title(const std::string& name) {
  if (name == "volume") return "volume (normalize, aspect, sparse grid)";
  if (name == "ground_truth") return "ground truth (ray-marched MIPs)";
  if (name == "fit") return "GMF fit";
  if (name == "train") return "training";
  if (name == "eval") return "evaluation";
  if (name == "orbit") return "orbit GIF";
  return "?";
}

// What the report reads back from the run folder.
struct RunFiles {
  Json volume, metrics, orbit;   // volume.json, eval/metrics.json, orbit.json
  gmf::Checkpoint fit, trained;  // gmf.ply, train/final.ply
};

RunFiles read_run_files(const fs::path& dir) {
  return {read_json(dir / "volume.json"), read_json(dir / "eval" / "metrics.json"), read_json(dir / "orbit.json"),
          gmf::load_checkpoint((dir / "gmf.ply").string()),
          gmf::load_checkpoint((dir / "train" / "final.ply").string())};
}

std::string header_section(const RunFiles& f, splat::Backend backend) {
  std::string md;
  md += "# hisnegs run: " + fs::path(f.volume.at("source").get<std::string>()).filename().string() + "\n\n";
  md += strf("Written by hisnegs %s on %s.  \n", HISNEGS_VERSION, now_utc().c_str());
  md += "Machine: " + machine_description() + "; back end: " + std::string(splat::to_string(backend)) + ".  \n";
  md += "Configuration: [config.yaml](config.yaml) (the effective settings); stage record: [run.json](run.json).\n\n";
  return md;
}

std::string summary_section(const RunFiles& f, const Json& run_state, const RunSummary& summary) {
  const Json &volume = f.volume, &metrics = f.metrics, &psnr = f.metrics.at("psnr");
  const auto shape = volume.at("shape_xyz").get<std::array<int, 3>>();
  const auto spacing = volume.at("spacing_um").get<std::array<double, 3>>();
  const auto aspect = volume.at("aspect").get<std::array<double, 3>>();
  Table s{{"", ""}, {}};
  s.add({"Volume", volume.at("source").get<std::string>()});
  s.add({"Shape X x Y x Z", strf("%d x %d x %d", shape[0], shape[1], shape[2])});
  s.add({"Spacing (um)", strf("%.4g, %.4g, %.4g", spacing[0], spacing[1], spacing[2])});
  s.add({"Aspect (world half-extents)", strf("%.4f, %.4f, %.4f", aspect[0], aspect[1], aspect[2])});
  s.add({"Normalization", volume.at("normalization").get<std::string>()});
  s.add({"Evaluation PSNR", strf("%.2f +- %.2f dB (min %.2f, max %.2f) over %d views", psnr.at("mean").get<double>(),
                                 psnr.at("std").get<double>(), psnr.at("min").get<double>(),
                                 psnr.at("max").get<double>(), metrics.at("views").get<int>())});
  if (metrics.contains("modes")) {  // the viewer's hard MIP beside the trained soft MIP
    const Json& modes = metrics.at("modes");
    auto at = [&](const char* mode, const char* what) { return modes.at(mode).at(what).at("mean").get<double>(); };
    s.add({"Hard MIP (what viewers show) / soft MIP",
           strf("%.2f / %.2f dB; foreground %.2f / %.2f dB (truth >= %g); %.0f%% of the hard MIP's error in the "
                "background",
                at("hard", "psnr"), at("soft", "psnr"), at("hard", "psnr_fg"), at("soft", "psnr_fg"),
                metrics.value("foreground_level", 0.2), 100 * at("hard", "background_error_share"))});
  }
  if (metrics.contains("halos")) {  // gmf/core/halo.hpp
    const Json& h = metrics.at("halos");
    s.add({"Halos (Gaussians brighter than the stack at their centre)",
           strf("%lld (%.2f%% of K; margin: the stack's noise, %.3g)", h.at("count").get<long long>(),
                100 * h.at("share").get<double>(), h.at("noise").get<double>())});
  }
  s.add({"Evaluation MAE / SSIM",
         strf("%.5f / %.4f", metrics.at("mae").at("mean").get<double>(), metrics.at("ssim").at("mean").get<double>())});
  s.add({"Rendering",
         strf("%s MIP, beta %.4g", metrics.at("mode").get<std::string>().c_str(), metrics.at("beta").get<double>())});
  if (run_state.contains("fit")) {
    s.add({"GMF fit", strf("K %zu, 3D PSNR %.2f dB (%s)", f.fit.mixture.size(), run_state["fit"].value("psnr_3d", 0.0),
                           run_state["fit"].value("stop", "").c_str())});
  }
  s.add({"Trained model",
         strf("K %zu ([train/final.ply](train/final.ply))%s", f.trained.mixture.size(),
              kept_initial_model(f.trained.meta) ? ": the fit itself, because training made the training views worse "
                                                   "(train.keep_better_init)"
                                                 : "")});
  double all_stages = 0;
  for (const StageTiming& t : summary.stages) all_stages += t.seconds;
  s.add({"Wall time", strf("%s for all stages; this invocation %s", format_seconds(all_stages).c_str(),
                           format_seconds(summary.seconds).c_str())});
  return "## Summary\n\n" + s.markdown() + "\n";
}

std::string stages_section(const RunSummary& summary) {
  Table st{{"stage", "wall time", "this invocation"}, {}};
  for (const StageTiming& t : summary.stages) {
    st.add({stage_title(t.name), format_seconds(t.seconds), t.reused ? "reused" : "ran"});
  }
  return "## Stages\n\n" + st.markdown() + "\n";
}

std::string evaluation_section(const Json& metrics) {
  const Json& psnr = metrics.at("psnr");
  std::string md = "## Evaluation views (report Table 8)\n\n";
  md += strf(
      "Soft-MIP splats of the trained model against ray-marched ground truth at the %d held-out evaluation "
      "views (CONVENTIONS \"Metrics\"); per view also in [eval/metrics.csv](eval/metrics.csv).\n\n",
      metrics.at("views").get<int>());
  Table v{{"view", "name", "PSNR (dB)", "MAE", "SSIM", "visible K"}, {}};
  for (const Json& row : metrics.at("per_view")) {
    v.add({std::to_string(row.at("view").get<int>()), row.at("name").get<std::string>(),
           strf("%.2f", row.at("psnr").get<double>()), strf("%.5f", row.at("mae").get<double>()),
           strf("%.4f", row.at("ssim").get<double>()), std::to_string(row.at("visible").get<int>())});
  }
  v.add({"mean", "", strf("%.2f", psnr.at("mean").get<double>()),
         strf("%.5f", metrics.at("mae").at("mean").get<double>()),
         strf("%.4f", metrics.at("ssim").at("mean").get<double>()),
         strf("%.0f", metrics.at("visible").at("mean").get<double>())});
  v.add({"std", "", strf("%.2f", psnr.at("std").get<double>()), strf("%.5f", metrics.at("mae").at("std").get<double>()),
         strf("%.4f", metrics.at("ssim").at("std").get<double>()),
         strf("%.0f", metrics.at("visible").at("std").get<double>())});
  md += v.markdown() + "\n";
  md += "Ground truth | render | absolute error (views 0, 10, 20):\n\n";
  for (int i : {0, 10, 20}) {
    if (i < metrics.at("views").get<int>()) md += strf("![view %d](eval/compare/%03d.png)\n", i, i);
  }
  return md + "\n";
}

std::string training_section(const fs::path& dir) {
  std::string md = "## Training\n\n";
  const std::vector<std::string> last = last_log_row(dir / "train" / "log.csv");
  if (last.size() >= 5) {
    md += "Last epoch " + last[0] + ": loss " + last[2] + ", training-view PSNR " + strf("%.2f", std::stod(last[3])) +
          " dB, K " + last[4] + ", " + format_seconds(std::stod(last[1])) +
          " of training. Log: [train/log.csv](train/log.csv).\n\n";
  }
  return md + "![training curve](train/training_curve.png)\n\n";
}

std::string gaussian_section(const RunFiles& f) {
  return "## Gaussian statistics (report Table 3)\n\n" +
         gaussian_table({{"GMF fit (gmf.ply)", gmf::compute_stats(f.fit.mixture)},
                         {"trained (train/final.ply)", gmf::compute_stats(f.trained.mixture)}})
             .markdown() +
         "\n";
}

std::string memory_section(const fs::path& dir, const RunFiles& f) {
  MemoryInputs mem;
  mem.shape_xyz = f.volume.at("shape_xyz").get<std::array<int, 3>>();
  mem.gaussians = f.trained.mixture.size();
  mem.sparse_file = std::pair{std::string("volume.vdb"), file_bytes((dir / "volume.vdb").string())};
  mem.checkpoint_file = std::pair{std::string("train/final.ply"), file_bytes((dir / "train" / "final.ply").string())};
  return "## Memory and compression (report Table 12)\n\n" + memory_table(mem).markdown() + "\n" +
         strf("The source TIFF file is %s on disk.\n\n", format_bytes(f.volume.at("file_bytes").get<double>()).c_str());
}

std::string orbit_section(const Json& orbit) {
  std::string md = "## Orbit (report Table 10)\n\n";
  md += strf(
      "%d frames of a 360 degree orbit at %.3g degrees elevation, %dx%d, K %zu, %s back end "
      "(render time per frame, the GIF encoding excluded):\n\n",
      orbit.at("frames").get<int>(), orbit.at("elevation_deg").get<double>(), orbit.at("width").get<int>(),
      orbit.at("height").get<int>(), orbit.at("gaussians").get<std::size_t>(),
      orbit.at("backend").get<std::string>().c_str());
  md += frame_time_table(orbit.at("seconds_per_frame").get<std::vector<double>>()).markdown() + "\n";
  return md + "![orbit](orbit.gif)\n";
}

}  // namespace

void write_run_report(const fs::path& dir, const Json& run_state, const RunSummary& summary, splat::Backend backend) {
  const RunFiles files = read_run_files(dir);
  const std::string md = header_section(files, backend) + summary_section(files, run_state, summary) +
                         stages_section(summary) + evaluation_section(files.metrics) + training_section(dir) +
                         gaussian_section(files) + memory_section(dir, files) + orbit_section(files.orbit);
  io::write_file_atomic(dir / "report.md", md.data(), md.size());
}

}  // namespace hisnegs::apps
