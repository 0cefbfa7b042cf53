// placeholder (issue 7)
#include "apps/cli_support.hpp"
namespace hisnegs::apps {
void add_run_command(CLI::App&, GlobalOptions&) {}
}  // namespace hisnegs::apps
