// Pieces shared by several hisnegs commands (e.g. `demo` reuses `synth` and `vdb`).
// Each prints its own progress line unless quiet.
#pragma once

#include <filesystem>

#include "apps/app_config.hpp"
#include "gmf/checkpoint.hpp"
#include "gmf/gaussian_mixture.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/synthetic_neuron.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/ground_truth.hpp"
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

// Checkpoint metadata of a model fitted to `loaded` (shape, spacing, aspect, normalization, source).
gmf::CheckpointMeta checkpoint_meta(const io::LoadedVolume& loaded, const std::string& source);

}  // namespace hisnegs::apps
