// Pieces shared by several hisnegs commands (e.g. `demo` reuses `synth` and `vdb`).
// Each prints its own progress line unless quiet.
#pragma once

#include <filesystem>

#include "apps/pipeline/app_config.hpp"
#include "gmf/checkpoint.hpp"
#include "gmf/gaussian_mixture.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/synthetic_neuron.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/ground_truth.hpp"
#include "splat/metrics.hpp"
#include "splat/splat_renderer.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::apps {

// Generates the synthetic stack and writes it as uint16 TIFF with its spacing.
io::Volume write_synthetic_stack(const std::filesystem::path& out, const io::SyntheticNeuronOptions& options,
                                 bool quiet);

// Loads + normalizes `volume_path`, builds the sparse grid and writes it to `out`.
io::SparseGrid write_sparse_grid(const std::filesystem::path& volume_path, const io::VolumeOptions& volume,
                                 const io::SparseGridOptions& sparse, const std::filesystem::path& out, bool quiet);

// Ray-marches `cameras` and writes DIR/{cameras.json, mips.tif, previews/NNN.png,
// meta.json}; `label` names the set in progress lines.
void write_ground_truth_set(const std::filesystem::path& dir, const std::string& label,
                            const splat::CameraSet& cameras, const io::LoadedVolume& loaded,
                            const std::string& volume_path, const splat::RaymarchOptions& raymarch,
                            splat::Backend backend, bool quiet);

// Writes `stack` as DIR/NAME (float32 TIFF, one page per view) and DIR/previews/NNN.png.
void write_image_stack(const std::filesystem::path& dir, const std::string& name, const splat::MipStack& stack);

// What the GMF stage starts from: the normalized volume, its samples (with the
// fit's background share) and the mixture initialized on the foreground grid.
struct FitSetup {
  io::LoadedVolume loaded;
  io::SparseGrid grid;
  gmf::GaussianMixture mixture;
};
// Loads `volume_path` and prepares the fit (config sections volume, sparse_grid, gmf);
// prints one line `label: ...` unless quiet.
FitSetup prepare_fit(const std::string& volume_path, const AppConfig& config, const char* label, bool quiet);

// The GMF stage: prepare_fit(), the Ceres/Adam fit (config section gmf, validated by
// the caller), the checkpoint `out` and, unless empty, the iteration log `log_csv`.
struct FitOutcome {
  std::size_t gaussians = 0;
  double psnr_3d = 0;  // of the final mixture against the normalized volume
  double seconds = 0;  // wall time including loading
  std::string stop_reason;
};
FitOutcome fit_to_checkpoint(const std::string& volume, const AppConfig& config, const std::filesystem::path& out,
                             const std::filesystem::path& log_csv, bool quiet);

// Stage-2 training (config sections train, splat): RUN/log.csv, RUN/checkpoints/,
// RUN/final.ply, RUN/training_curve.png. Refuses a RUN holding a run unless `resume`.
struct TrainRequest {
  std::filesystem::path init;  // initial checkpoint (.ply)
  std::filesystem::path data;  // a ground-truth set (cameras.json + mips.tif), e.g. GTDIR/train
  std::filesystem::path run;
  splat::Backend backend = splat::Backend::kCpu;
  bool resume = false;
};
struct TrainOutcome {
  int epochs = 0;
  int gaussians = 0;
  double psnr = 0;     // mean training-view PSNR of the last epoch
  double seconds = 0;  // training wall time, earlier sessions of a resumed run included
};
TrainOutcome train_model(const TrainRequest& request, const AppConfig& config, bool quiet);

// Renders `model` at the views of the ground-truth set `set` (cameras.json + mips.tif)
// with config section splat and measures each view (CONVENTIONS "Metrics"):
// DIR/metrics.json, DIR/metrics.csv, DIR/compare/NNN.png.
struct EvalOutcome {
  int views = 0;
  splat::MetricSummary psnr, mae, ssim;
};
EvalOutcome evaluate_model(const std::filesystem::path& model, const std::filesystem::path& set,
                           const std::filesystem::path& dir, const AppConfig& config, splat::Backend backend,
                           bool quiet);

// Renders an N-frame 360 degree turntable orbit (camera intrinsics, elevation in
// degrees) and writes it as an animated GIF; returns the render time of each frame.
std::vector<double> write_orbit_gif(const std::filesystem::path& gif, splat::SplatRenderer& renderer,
                                    std::span<const float> params, const splat::CameraOptions& camera,
                                    const splat::SplatSettings& settings, int frames, double elevation_deg,
                                    int delay_ms);

// Checkpoint metadata of a model fitted to `loaded` (shape, spacing, aspect, normalization, source).
gmf::CheckpointMeta checkpoint_meta(const io::LoadedVolume& loaded, const std::string& source);

}  // namespace hisnegs::apps
