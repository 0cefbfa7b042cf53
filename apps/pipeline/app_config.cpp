// SPDX-License-Identifier: Apache-2.0
// AppConfig loading/dumping through io::ConfigFile and each section's visit().
#include "apps/pipeline/app_config.hpp"

#include "io/error.hpp"

namespace hisnegs::apps {

void AppConfig::validate() const {
  volume.validate();
  background.validate();
  sparse_grid.validate();
  synth.validate();
  camera.validate();
  raymarch.validate();
  splat.validate();
  train.validate();
  gmf.validate();
}

namespace {

AppConfig overlay(const io::ConfigFile& file, const std::string& origin) {
  AppConfig config;
  file.check_sections({"volume", "background", "sparse_grid", "synth", "camera", "raymarch", "splat", "train", "gmf"});
  config.for_each_section([&](const char* name, auto& options) { file.read(name, options); });
  try {
    config.validate();
  } catch (const io::InputError& e) {
    throw io::InputError(origin + ": " + e.what());
  }
  return config;
}

}  // namespace

AppConfig load_app_config(const std::optional<std::filesystem::path>& path) {
  if (!path) {
    AppConfig config;
    config.validate();
    return config;
  }
  return overlay(io::ConfigFile::load(*path), path->string());
}

AppConfig load_app_config_text(const std::string& text, const std::string& origin) {
  return overlay(io::ConfigFile::parse(text, origin), origin);
}

std::string dump_app_config(AppConfig config) {
  io::ConfigWriter writer;
  bool first = true;
  config.for_each_section([&](const char* name, auto& options) {
    if (!first) writer.blank_line();
    first = false;
    writer.begin_section(name);
    options.visit(writer);
  });
  return writer.str();
}

}  // namespace hisnegs::apps
