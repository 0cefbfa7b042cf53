// SPDX-License-Identifier: Apache-2.0
// The volume side of stage 2: the fit's samples of the stack (its
// sparse grid with gmf.background_fraction, weights from gmf.background_weight)
// and the empty-space test (outside the foreground and its band), as the
// trainer's VolumeTerm. Knows no trainer loop.
#pragma once

#include <filesystem>
#include <memory>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "gmf/core/checkpoint.hpp"
#include "splat/volume_term.hpp"

namespace hisnegs::apps {

// Reads `volume` with the config's volume options (whole, or tile by tile when it does
// not fit under reading.max_memory: the same samples), checks that it spans the world
// box the model `meta` was fitted to (io::InputError naming the file otherwise) and
// builds the term with the model's own 3D aggregation. One line "train: ...".
std::shared_ptr<const splat::VolumeTerm> make_training_volume(const std::filesystem::path& volume,
                                                              const io::VolumeOptions& volume_options,
                                                              const io::SparseGridOptions& sparse_grid,
                                                              const gmf::GmfOptions& gmf,
                                                              const gmf::CheckpointMeta& meta,
                                                              const StackReading& reading,
                                                              const Progress& progress);

}  // namespace hisnegs::apps
