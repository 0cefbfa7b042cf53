// SPDX-License-Identifier: Apache-2.0
// make_training_volume: the stack's samples and empty-space test for the trainer.
#include "apps/pipeline/training_volume.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <span>

#include "apps/pipeline/format.hpp"
#include "gmf/samples.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/stack_file.hpp"
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
  // A stack read by tiles hands its background samples over tile by tile, one block
  // per 8³ leaf as extract_samples makes them, straight into float samples: kept in
  // the grid, scattered samples would cost a leaf each (as much as the stack).
  const io::StackHeader header = io::inspect_stack(volume, io::stack_read_options(volume_options));
  const io::WorldFrame stack =
      io::stack_frame(header.nx, header.ny, header.nz, header.spacing, volume_options.aspect, volume);
  const double fraction = options.background_fraction;
  const float background_weight =
      fraction > 0 ? static_cast<float>(std::sqrt(gmf.background_weight / fraction)) : 0.0f;
  // Each taken leaf's samples as one block, with the leaf's origin for the order.
  struct TakenLeaf {
    std::array<int, 3> origin;
    std::size_t begin, end;
  };
  std::vector<TakenLeaf> leaves;
  splat::VolumeSamples background;
  const auto take = [&](const std::array<int, 3>& origin, std::span<const io::ActiveVoxel> voxels) {
    if (background_weight <= 0 || voxels.empty()) return;
    if (background.x.capacity() == 0) {  // the expected count and five standard deviations: no doubling
      const double n = static_cast<double>(header.nx) * header.ny * header.nz;
      const auto expected = static_cast<std::size_t>(n * fraction + 5.0 * std::sqrt(n * fraction * (1.0 - fraction)));
      for (auto* part : {&background.x, &background.y, &background.z, &background.value, &background.weight}) {
        part->reserve(expected);
      }
    }
    leaves.push_back({origin, background.size(), background.size() + voxels.size()});
    for (const io::ActiveVoxel& v : voxels) {
      const Eigen::Vector3d p = stack.world_from_index(Eigen::Vector3d(v.index[0], v.index[1], v.index[2]));
      background.x.push_back(static_cast<float>(p.x()));
      background.y.push_back(static_cast<float>(p.y()));
      background.z.push_back(static_cast<float>(p.z()));
      background.value.push_back(v.value);
      background.weight.push_back(background_weight);
    }
  };
  gmf::require_same_world_box(meta, stack, volume.string());  // before the stack is read
  auto grid = std::make_shared<io::SparseGrid>(
      read_sparse_grid(volume, volume_options, options, reading, "train", progress, take));
  // The order of the whole stack's term (extract_samples): the foreground's blocks,
  // then the background's in the grid's leaf order, so that the trainer's batches
  // pick the same blocks whatever the memory limit. Taken leaves come in tile order.
  splat::VolumeSamples samples;
  {
    const gmf::SampleSet set = gmf::extract_samples(*grid, gmf.background_weight, 8);
    const auto copy = [](std::vector<float>& to, const std::vector<double>& from, std::size_t extra) {
      to.reserve(from.size() + extra);
      to.assign(from.begin(), from.end());
    };
    copy(samples.x, set.x, background.size());
    copy(samples.y, set.y, background.size());
    copy(samples.z, set.z, background.size());
    copy(samples.value, set.value, background.size());
    copy(samples.weight, set.weight, background.size());
    samples.block_begin.assign(set.block_begin.begin(), set.block_begin.end());
  }
  std::sort(leaves.begin(), leaves.end(), [](const TakenLeaf& a, const TakenLeaf& b) {
    return io::SparseGrid::leaf_order_key(a.origin) < io::SparseGrid::leaf_order_key(b.origin);
  });
  for (const TakenLeaf& leaf : leaves) {
    const auto append = [&](std::vector<float>& to, const std::vector<float>& from) {
      to.insert(to.end(), from.begin() + static_cast<std::ptrdiff_t>(leaf.begin),
                from.begin() + static_cast<std::ptrdiff_t>(leaf.end));
    };
    append(samples.x, background.x);
    append(samples.y, background.y);
    append(samples.z, background.z);
    append(samples.value, background.value);
    append(samples.weight, background.weight);
    samples.block_begin.push_back(static_cast<std::uint32_t>(samples.size()));
  }
  background = {};
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
