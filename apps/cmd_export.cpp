// placeholder (issue 8)
#include "apps/cli_support.hpp"
namespace hisnegs::apps {
void add_export_command(CLI::App&, GlobalOptions&) {}
void add_import_command(CLI::App&, GlobalOptions&) {}
}  // namespace hisnegs::apps
