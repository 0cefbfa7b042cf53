// SPDX-License-Identifier: Apache-2.0
// render_model: the views of a cameras file and/or an orbit GIF, and render.json.
#include "apps/pipeline/render_model.hpp"

#include <algorithm>
#include <nlohmann/json.hpp>

#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/hierarchy.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::apps {
namespace {

// The other ranks' shares of the model, through the job (distributed.hpp).
class JobShares final : public splat::ShareCombiner {
 public:
  explicit JobShares(const Job& job) : job_(job) {}
  void max(std::span<float> image) const override { job_.max_to_root(image); }
  void merge_soft(std::span<splat::SoftPixel> pixels) const override { job_.merge_soft_to_root(pixels); }

 private:
  const Job& job_;
};

// The upper median in ms (render.json's convention).
double median_ms(std::vector<double> seconds) {
  if (seconds.empty()) return 0;
  std::sort(seconds.begin(), seconds.end());
  return 1e3 * seconds[seconds.size() / 2];
}

}  // namespace

void render_model(const RenderRequest& request, const RenderConfig& config, const Progress& progress) {
  config.get<&AppConfig::splat>().validate();
  config.get<&AppConfig::camera>().validate();
  if (request.cameras.empty() && !request.orbit) throw io::InputError("render: give --cameras FILE and/or --orbit N");
  gmf::Checkpoint checkpoint;
  open_on_every_rank(job(), [&] { checkpoint = gmf::load_checkpoint(request.model.string()); });
  // On several MPI ranks each renders a contiguous share of the Gaussians and the
  // images meet on rank 0 (hard: the max; soft: the softmax states merged), which
  // alone writes.
  const Job& ranks = job();
  const std::size_t K = checkpoint.mixture.size();
  const std::size_t first = K * static_cast<std::size_t>(ranks.rank()) / static_cast<std::size_t>(ranks.size());
  const std::size_t last = K * static_cast<std::size_t>(ranks.rank() + 1) / static_cast<std::size_t>(ranks.size());
  const auto params = splat::flat_params(checkpoint.mixture)
                          .subspan(gmf::kGaussianParamCount * first, gmf::kGaussianParamCount * (last - first));
  const JobShares job_shares(ranks);
  const splat::ShareCombiner* shares = ranks.distributed() ? &job_shares : nullptr;
  if (ranks.distributed()) {
    progress.say("render: %d MPI ranks, each renders its share of the %zu Gaussians (this rank %zu); rank 0 "
                 "combines and writes", ranks.size(), K, last - first);
  }
  const splat::SplatSettings settings = splat::SplatSettings::from(config.get<&AppConfig::splat>());
  const splat::BackgroundFloors floors =
      splat::floors_of(checkpoint.meta, request.model.string(), config.get<&AppConfig::splat>().background);
  auto renderer = splat::make_splat_renderer(request.backend);
  const std::filesystem::path& dir = request.dir;
  const char* mode = settings.mode == splat::MipMode::kSoftmax ? "soft" : "hard";
  const std::string backend(splat::to_string(request.backend));
  nlohmann::ordered_json meta;
  meta["model"] = io::printable(request.model.string(), 500);
  meta["gaussians"] = checkpoint.mixture.size();
  meta["mode"] = mode;
  meta["beta"] = settings.beta;
  meta["backend"] = backend;
  meta["background"] = floors.none() ? "none" : "the model's floor";
  if (!request.cameras.empty()) {
    const splat::CameraSet cameras = splat::read_cameras_json(request.cameras);
    splat::RenderedViews r;
    if (request.lod) {
      if (ranks.distributed()) throw io::InputError("render: --lod runs in one process (not on MPI ranks)");
      const gmf::Hierarchy h = gmf::hierarchy_of(request.model, checkpoint);
      std::vector<std::size_t> drawn;
      r = splat::render_views_lod(*renderer, h, cameras, settings, *request.lod, floors, &drawn);
      meta["lod"] = {{"pixels", request.lod->pixels}, {"budget", request.lod->budget}, {"nodes", h.nodes.size()},
                     {"levels", h.depth() + 1}, {"gaussians_per_view", drawn}};
      progress.say("render: level of detail: %zu nodes on %d levels (%zu Gaussians in all); view 0 draws %zu of "
                   "the model's %zu", h.nodes.size(), h.depth() + 1, h.gaussians.size(),
                   drawn.empty() ? std::size_t{0} : drawn[0], checkpoint.mixture.size());
    } else {
      r = splat::render_views(*renderer, params, cameras, settings, {}, floors, shares);
    }
    const splat::MipStack& s = r.stack;
    if (ranks.root()) write_image_stack(dir, "render.tif", s);
    meta["cameras"] = io::printable(request.cameras.string(), 500);
    meta["views"] = s.views;
    meta["width"] = s.width;
    meta["height"] = s.height;
    meta["median_ms_per_view"] = median_ms(s.seconds_per_view);
    progress.say("render: %d views of %dx%d, K %zu (%d visible in view 0), %s MIP%s, %s, median %.2f ms/view -> %s",
                 s.views, s.width, s.height, checkpoint.mixture.size(), r.stats.empty() ? 0 : r.stats[0].visible, mode,
                 floors.none() ? "" : " over the background's floor", backend.c_str(), median_ms(s.seconds_per_view),
                 (dir / "render.tif").c_str());
  }
  if (request.orbit) {
    const OrbitOptions& o = *request.orbit;
    const std::vector<double> seconds = write_orbit_gif(ranks.root() ? dir / "orbit.gif" : std::filesystem::path(),
                                                        *renderer, params, config, o, floors, shares);
    meta["orbit"] = {
        {"frames", o.frames}, {"elevation_deg", o.elevation_deg}, {"median_ms_per_frame", median_ms(seconds)}};
    progress.say("render: orbit of %d frames at %.3g deg elevation, median %.2f ms/frame -> %s", o.frames,
                 o.elevation_deg, median_ms(seconds), (dir / "orbit.gif").c_str());
  }
  if (!ranks.root()) return;
  if (ranks.distributed()) meta["mpi_ranks"] = ranks.size();
  const std::string text = meta.dump(2) + "\n";
  io::write_file_atomic(dir / "render.json", text.data(), text.size());
}

}  // namespace hisnegs::apps
