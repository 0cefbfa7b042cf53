// SPDX-License-Identifier: Apache-2.0
// The hisnegs executable.
#include "apps/cli/cli_support.hpp"

int main(int argc, char** argv) { return hisnegs::apps::run_cli(argc, argv); }
