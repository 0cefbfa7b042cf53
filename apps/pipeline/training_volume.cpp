// SPDX-License-Identifier: Apache-2.0
// make_training_volume: the stack's samples and empty-space test for the trainer.
#include "apps/pipeline/training_volume.hpp"

#include <cmath>

#include "apps/pipeline/format.hpp"
#include "gmf/samples.hpp"
#include "io/sparse_grid.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

std::shared_ptr<const splat::VolumeTerm> make_training_volume(const std::filesystem::path& volume,
                                                              const io::VolumeOptions& volume_options,
                                                              const io::SparseGridOptions& sparse_grid,
                                                              const gmf::GmfOptions& gmf,
                                                              const gmf::CheckpointMeta& meta,
                                                              const StackReading& reading,
                                                              const Progress& progress) {
  io::Stopwatch watch;
  io::SparseGridOptions options = sparse_grid;
  options.background_fraction = gmf.background_fraction;  // the fit's samples of empty space
  auto grid =
      std::make_shared<io::SparseGrid>(read_sparse_grid(volume, volume_options, options, reading, "train", progress));
  gmf::require_same_world_box(meta, grid->frame(), volume.string());
  const gmf::SampleSet set = gmf::extract_samples(*grid, gmf.background_weight, 8);
  splat::VolumeSamples samples;
  const auto narrow = [](const std::vector<double>& v) { return std::vector<float>(v.begin(), v.end()); };
  samples.x = narrow(set.x);
  samples.y = narrow(set.y);
  samples.z = narrow(set.z);
  samples.value = narrow(set.value);
  samples.weight = narrow(set.weight);
  samples.block_begin.assign(set.block_begin.begin(), set.block_begin.end());
  const io::WorldFrame frame = grid->frame();
  // Empty: the voxel nearest the point is outside the volume or not active
  // (neither foreground nor within the band around it).
  splat::EmptySpaceTest empty = [grid, frame](const double world[3]) {
    const Eigen::Vector3d ijk = frame.index_from_world(Eigen::Vector3d(world[0], world[1], world[2]));
    const Eigen::Vector3i& shape = frame.shape();
    int index[3];
    for (int a = 0; a < 3; ++a) {
      const double r = std::round(ijk[a]);
      if (!(r >= 0 && r < shape[a])) return true;
      index[a] = static_cast<int>(r);
    }
    bool active = false;
    (void)grid->value(index[0], index[1], index[2], &active);
    return !active;
  };
  const gmf::MixtureModel model = gmf::model_of(meta, gmf.mahalanobis_cutoff);
  progress.say("train: 3D term on %s: %zu samples in %zu blocks, the model's %s, %s", volume.c_str(), samples.size(),
               samples.blocks(), gmf::describe(model).c_str(), format_seconds(watch.elapsed()).c_str());
  return std::make_shared<splat::VolumeTerm>(std::move(samples), model, std::move(empty));
}

}  // namespace hisnegs::apps
