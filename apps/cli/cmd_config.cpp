// SPDX-License-Identifier: Apache-2.0
// `hisnegs config [--check FILE]`: print the effective configuration as YAML.
#include <cstdio>

#include "apps/cli/cli_support.hpp"

namespace hisnegs::apps {

void add_config_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("config", "print the effective configuration (defaults + --config) as YAML");
  cmd->callback([&global] { std::fputs(dump_app_config(global.config()).c_str(), stdout); });
}

}  // namespace hisnegs::apps
