// SPDX-License-Identifier: Apache-2.0
// The whole configuration of a hisnegs run: one options struct per section of
// configs/*.yaml, loading (strict), validation and YAML dumping. Defines no
// option itself: every field lives in its layer's FooOptions.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "gmf/gmf_options.hpp"
#include "gmf/core/background.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "apps/simulate/synthetic_neuron.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::apps {

struct AppConfig {
  io::VolumeOptions volume;
  gmf::BackgroundOptions background;
  io::SparseGridOptions sparse_grid;
  simulate::SyntheticNeuronOptions synth;
  splat::CameraOptions camera;
  splat::RaymarchOptions raymarch;
  splat::SplatOptions splat;
  splat::TrainOptions train;
  gmf::GmfOptions gmf;

  // Calls f(section_name, options) for every section, in file order.
  template <class F>
  void for_each_section(F&& f) {
    f("volume", volume);
    f("background", background);
    f("sparse_grid", sparse_grid);
    f("synth", synth);
    f("camera", camera);
    f("raymarch", raymarch);
    f("splat", splat);
    f("train", train);
    f("gmf", gmf);
  }
  void validate() const;  // every section's validate()
};

// Defaults overlaid with the file's values (if a path is given), validated.
// Throws io::InputError naming the file, line, section and key.
AppConfig load_app_config(const std::optional<std::filesystem::path>& path);

// The same for YAML text (e.g. a built-in profile); `origin` names it in errors.
AppConfig load_app_config_text(const std::string& text, const std::string& origin);

// YAML text of every field (what configs/default.yaml holds for the defaults).
std::string dump_app_config(AppConfig config);

}  // namespace hisnegs::apps
