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

namespace {

// Each taken leaf's samples as one block, with the leaf's origin for the order.
struct TakenLeaf {
  std::array<int, 3> origin;
  std::size_t begin, end;
};

// The background samples a stack read by tiles hands over tile by tile, one block
// per 8³ leaf as extract_samples makes them, straight into float samples: kept in
// the grid, scattered samples would cost a leaf each (as much as the stack).
struct BackgroundTaker {
  explicit BackgroundTaker(const io::WorldFrame& frame) : stack(frame) {}
  const io::WorldFrame& stack;
  double fraction = 0;  // of the background voxels sampled
  float weight = 0;     // each sample's
  std::size_t voxels = 0;
  std::vector<TakenLeaf> leaves;
  splat::VolumeSamples samples;

  void take(const std::array<int, 3>& origin, std::span<const io::ActiveVoxel> active) {
    if (weight <= 0 || active.empty()) return;
    if (samples.x.capacity() == 0) {  // the expected count and five standard deviations: no doubling
      const auto n = static_cast<double>(voxels);
      const auto expected = static_cast<std::size_t>(n * fraction + 5.0 * std::sqrt(n * fraction * (1.0 - fraction)));
      for (auto* part : {&samples.x, &samples.y, &samples.z, &samples.value, &samples.weight}) part->reserve(expected);
    }
    leaves.push_back({origin, samples.size(), samples.size() + active.size()});
    for (const io::ActiveVoxel& v : active) {
      const Eigen::Vector3d p = stack.world_from_index(Eigen::Vector3d(v.index[0], v.index[1], v.index[2]));
      samples.x.push_back(static_cast<float>(p.x()));
      samples.y.push_back(static_cast<float>(p.y()));
      samples.z.push_back(static_cast<float>(p.z()));
      samples.value.push_back(v.value);
      samples.weight.push_back(weight);
    }
  }
};

// The order of the whole stack's term (extract_samples): the foreground's blocks,
// then the background's in the grid's leaf order, so that the trainer's batches
// pick the same blocks whatever the memory limit. Taken leaves come in tile order.
splat::VolumeSamples ordered_samples(const io::SparseGrid& grid, double background_weight, BackgroundTaker& taken) {
  splat::VolumeSamples samples;
  const splat::VolumeSamples& background = taken.samples;
  {
    const gmf::SampleSet set = gmf::extract_samples(grid, background_weight, 8);
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
  std::sort(taken.leaves.begin(), taken.leaves.end(), [](const TakenLeaf& a, const TakenLeaf& b) {
    return io::SparseGrid::leaf_order_key(a.origin) < io::SparseGrid::leaf_order_key(b.origin);
  });
  for (const TakenLeaf& leaf : taken.leaves) {
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
  taken.samples = {};
  return samples;
}

// Empty: the voxel nearest the point is outside the volume or not active (neither
// foreground nor within the band around it).
splat::EmptySpaceTest empty_space_of(std::shared_ptr<const io::SparseGrid> grid) {
  const io::WorldFrame frame = grid->frame();
  return [grid = std::move(grid), frame](const double world[3]) {
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
}

}  // namespace

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
  const io::StackHeader header = io::inspect_stack(volume, io::stack_read_options(volume_options));
  const io::WorldFrame stack =
      io::stack_frame(header.nx, header.ny, header.nz, header.spacing, volume_options.aspect, volume);
  const double fraction = options.background_fraction;
  BackgroundTaker taker(stack);
  taker.fraction = fraction;
  taker.weight = fraction > 0 ? static_cast<float>(std::sqrt(gmf.background_weight / fraction)) : 0.0f;
  taker.voxels = static_cast<std::size_t>(header.nx) * header.ny * header.nz;
  const auto take = [&](const std::array<int, 3>& origin, std::span<const io::ActiveVoxel> voxels) {
    taker.take(origin, voxels);
  };
  gmf::require_same_world_box(meta, stack, volume.string());  // before the stack is read
  auto grid = std::make_shared<const io::SparseGrid>(
      read_sparse_grid(volume, volume_options, options, reading, "train", progress, take));
  splat::VolumeSamples samples = ordered_samples(*grid, gmf.background_weight, taker);
  const gmf::MixtureModel model = gmf::model_of(meta, gmf.mahalanobis_cutoff);
  progress.say("train: 3D term on %s: %zu samples in %zu blocks, the model's %s, %s", volume.c_str(), samples.size(),
               samples.blocks(), gmf::describe(model).c_str(), format_seconds(watch.elapsed()).c_str());
  return std::make_shared<splat::VolumeTerm>(std::move(samples), model, empty_space_of(std::move(grid)));
}

}  // namespace hisnegs::apps
