// SPDX-License-Identifier: Apache-2.0
// `hisnegs view --model m.ply [--volume V.tif] [--cameras cams.json] [--port 8080]
// [--host 127.0.0.1] [--no-browser]`: the `export html` page served over local HTTP
// until Ctrl-C, with the ray-marched MIP of the volume to compare against. Options
// and reporting only; the page is apps/viewer/viewer_page, what is served
// apps/viewer/viewer_session, the server apps/viewer/viewer_server.
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>

#include "apps/cli/cli_support.hpp"
#include "apps/viewer/viewer_session.hpp"
#include "apps/viewer/viewer_server.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/error.hpp"
#include "splat/camera.hpp"

extern char** environ;  // NOLINT(readability-redundant-declaration): POSIX declares it only under _GNU_SOURCE

namespace hisnegs::apps {
namespace {

constexpr const char* kOpener = "/usr/bin/xdg-open";

// Starts the desktop's browser on `url` without waiting for it; false when there is none.
bool open_browser(const std::string& url) {
  if (!std::filesystem::exists(kOpener)) return false;
  std::string opener = kOpener;
  std::string target = url;
  char* argv[] = {opener.data(), target.data(), nullptr};
  pid_t pid = 0;
  return posix_spawn(&pid, kOpener, nullptr, nullptr, argv, environ) == 0;
}

}  // namespace

void add_view_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("view", "serve the WebGL2 hard-MIP viewer of a checkpoint on local HTTP until Ctrl-C");
  struct Args {
    std::string model, volume, cameras;
    ViewerServerOptions server;
    bool no_browser = false;
    BackgroundOverride background;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("--model", args->model, "checkpoint (.ply or .hgs); re-read when it changes")->required();
  cmd->add_option("--volume", args->volume, "stack (TIFF or HDF5) the model was fitted to: compare with its ray-marched MIP");
  cmd->add_option("--cameras", args->cameras, "cameras.json whose views #view=N shows (default: eval orbit)");
  cmd->add_option("--port", args->server.port, "TCP port; 0 = any free port")->capture_default_str();
  cmd->add_option("--host", args->server.host, "address to bind (not loopback: reachable from the network)")
      ->capture_default_str();
  cmd->add_flag("--no-browser", args->no_browser, "do not open a browser");
  args->background.add_to(cmd);
  cmd->callback([args, &global] {
    // A FIFO or device is refused as every reader refuses it (it would hang the
    // server); a regular file that is bad or still being written is served as an
    // error page until it is fixed.
    io::require_regular_file(args->model);
    AppConfig config = global.config();
    args->background.apply(config.splat);
    ViewerSessionOptions options;
    options.model = args->model;
    options.cameras =
        args->cameras.empty() ? splat::evaluation_orbit(config.camera) : splat::read_cameras_json(args->cameras);
    options.page.cutoff = config.splat.mahalanobis_cutoff;
    options.page.low_pass = config.splat.low_pass;
    options.background = config.splat.background;
    if (!args->volume.empty()) options.volume = args->volume;
    options.volume_options = config.volume;
    options.raymarch = config.raymarch;
    ViewerSession session(options);
    // A bad model is reported here and on the page; the server still starts, so that
    // fixing the file and reloading the page is enough.
    std::string what;
    try {
      const gmf::Checkpoint checkpoint = session.model();
      what = std::to_string(checkpoint.mixture.size()) + " Gaussians";
    } catch (const std::exception& e) {
      std::fprintf(stderr, "view: error: %s\n", io::printable(e.what()).c_str());
      what = "not readable yet: the page shows the error until the file is fixed";
    }
    if (!is_loopback_host(args->server.host)) {
      std::fprintf(stderr, "view: warning: --host %s is not loopback: anyone who can reach it sees the model\n",
                   args->server.host.c_str());
    }
    const int sig = serve_viewer(session.routes(), args->server, [&](const std::string& url) {
      std::printf("view: serving %s (%s, %zu views%s) at %s ; %s#view=N&ui=0 shows view N; Ctrl-C stops\n",
                  args->model.c_str(), what.c_str(), options.cameras.views.size(),
                  session.has_volume() ? ", compared with the volume's MIP" : "", url.c_str(), url.c_str());
      std::fflush(stdout);
      if (!args->no_browser && !open_browser(url)) {
        std::printf("view: no %s here; open the URL in a browser\n", kOpener);
        std::fflush(stdout);
      }
    });
    if (!global.quiet) std::printf("view: stopped (%s)\n", sig == SIGINT ? "Ctrl-C" : "signal");
  });
}

}  // namespace hisnegs::apps
