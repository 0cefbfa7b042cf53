// SPDX-License-Identifier: Apache-2.0
// `hisnegs info FILE`: what a TIFF stack, .vdb, .ply or compact .hgs checkpoint holds
// (apps/pipeline/file_info.hpp), printed.
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/file_info.hpp"

namespace hisnegs::apps {

void add_info_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("info", "describe a stack (TIFF, HDF5, BigDataViewer, Imaris), an OpenVDB file or a checkpoint (.ply, .hgs)");
  auto path = std::make_shared<std::string>();
  auto overrides = std::make_shared<VolumeOverrides>();
  auto stack = std::make_shared<std::string>();
  cmd->add_option("FILE", *path, "stack (TIFF, HDF5 .h5, BigDataViewer .xml, Imaris .ims), .vdb, .ply or .hgs")->required();
  cmd->add_option("--volume", *stack,
                  "a checkpoint's stack: count its halos, the Gaussians brighter than the stack at their centre by "
                  "more than its noise");
  overrides->add_to(cmd);
  cmd->callback([path, stack, overrides, &global] {
    io::VolumeOptions volume = global.config().volume;
    overrides->apply(volume);
    std::fputs(describe_file(*path, volume, *stack).text().c_str(), stdout);
  });
}

}  // namespace hisnegs::apps
