// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the config reader: load_app_config (strict YAML through
// io::ConfigFile into every section's options, validated), and for every accepted
// file a dump/load round trip, whose dump must not change. Only io::InputError
// may escape; anything else is a finding.
#include <cstddef>
#include <cstdint>
#include <string>

#include "apps/pipeline/app_config.hpp"
#include "fuzz/fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const std::filesystem::path path = fuzz::write_input("config.yaml", data, size);
  apps::AppConfig config;
  try {
    config = apps::load_app_config(path);
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
    return 0;
  }
  // A run records dump_app_config as its effective configuration: it must load
  // back to the same options.
  const std::string dumped = apps::dump_app_config(config);
  const apps::AppConfig reloaded = apps::load_app_config_text(dumped, "<dump>");
  fuzz::require(apps::dump_app_config(reloaded) == dumped, "dump_app_config round-trips");
  return 0;
}
