// SPDX-License-Identifier: Apache-2.0
// The viewer's HTTP server on cpp-httplib (header-only, Debian libcpp-httplib-dev;
// kept in this file for build time). Clean shutdown: the signals are blocked and a
// sigwait thread stops the server, so no handler runs inside httplib's threads.
#include "apps/viewer/viewer_server.hpp"

#include <httplib.h>
#include <pthread.h>
#include <signal.h>

#include <atomic>
#include <cstdio>
#include <stdexcept>
#include <thread>

#include "io/error.hpp"

namespace hisnegs::apps {

bool is_loopback_host(const std::string& host) {
  return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

int serve_viewer(const std::string& page, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening) {
  if (options.port < 0 || options.port > 65535) {
    throw io::InputError("--port = " + std::to_string(options.port) + ": must be in [0, 65535]");
  }
  // Block before httplib starts its thread pool, so every thread inherits the mask.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  sigset_t previous;
  pthread_sigmask(SIG_BLOCK, &stop_signals, &previous);

  httplib::Server server;
  const auto serve_page = [&page](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(page, "text/html; charset=utf-8");
  };
  // Exact paths only: "/..", "/%2e%2e/", "//etc/passwd" and the like match nothing.
  server.Get("/", serve_page);
  server.Get("/index.html", serve_page);
  server.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
    if (res.status == 404) res.set_content("not found: hisnegs view serves / only\n", "text/plain");
    std::fprintf(stderr, "view: %d %s %s\n", res.status, req.method.c_str(), req.path.c_str());
  });

  int port = options.port;
  if (port == 0) {
    port = server.bind_to_any_port(options.host.c_str());
  } else if (!server.bind_to_port(options.host.c_str(), port)) {
    port = -1;
  }
  if (port < 0) {
    pthread_sigmask(SIG_SETMASK, &previous, nullptr);
    throw io::InputError("view: cannot listen on " + options.host + ":" + std::to_string(options.port) +
                             " (in use, or not an address of this machine)");
  }
  const bool v6 = options.host.find(':') != std::string::npos;
  const std::string url =
      "http://" + (v6 ? "[" + options.host + "]" : options.host) + ":" + std::to_string(port) + "/";

  std::atomic<int> received{0};
  std::thread waiter([&] {
    int sig = 0;
    sigwait(&stop_signals, &sig);
    received = sig;
    server.stop();
  });
  on_listening(url);
  server.listen_after_bind();
  if (received == 0) {  // stopped for another reason: wake the waiter
    pthread_kill(waiter.native_handle(), SIGTERM);
  }
  waiter.join();
  pthread_sigmask(SIG_SETMASK, &previous, nullptr);
  return received;
}

}  // namespace hisnegs::apps
