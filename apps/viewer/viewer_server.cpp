// SPDX-License-Identifier: Apache-2.0
// The viewer's HTTP server on cpp-httplib (header-only, Debian libcpp-httplib-dev;
// kept in this file for build time). Clean shutdown on SIGINT/SIGTERM whichever
// thread receives it (TBB's workers, started before the server, included): the
// handler only writes the signal number into a pipe, and a waiter thread reading
// it stops the server.
#include "apps/viewer/viewer_server.hpp"

#include <httplib.h>
#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <stdexcept>
#include <thread>

#include "io/error.hpp"

namespace hisnegs::apps {

bool is_loopback_host(const std::string& host) {
  return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

namespace {

// The write end of the running server's signal pipe (one server per process at a time).
std::atomic<int> g_signal_pipe{-1};

extern "C" void on_stop_signal(int sig) {
  const unsigned char byte = static_cast<unsigned char>(sig);
  const int fd = g_signal_pipe.load();
  if (fd >= 0) (void)!::write(fd, &byte, 1);  // async-signal-safe
}

void send(const ViewerReply& reply, httplib::Response& res) {
  res.status = reply.status;
  res.set_header("Cache-Control", "no-store");
  for (const auto& [name, value] : reply.headers) res.set_header(name, value);
  res.set_content(reply.body, reply.content_type);
}

// Runs `route`; an exception becomes a 500 with its text and one stderr line.
template <class Route>
void answer(const httplib::Request& req, httplib::Response& res, Route&& route) {
  try {
    send(route(), res);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "view: 500 %s %s: %s\n", req.method.c_str(), req.path.c_str(), e.what());
    res.status = 500;
    res.set_content(std::string(e.what()) + "\n", "text/plain; charset=utf-8");
  }
}

}  // namespace

int serve_viewer(const ViewerRoutes& routes, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening) {
  if (options.port < 0 || options.port > 65535) {
    throw io::InputError("--port = " + std::to_string(options.port) + ": must be in [0, 65535]");
  }
  if (!routes.page) throw std::invalid_argument("serve_viewer: no page route");
  httplib::Server server;
  const auto serve_page = [&routes](const httplib::Request& req, httplib::Response& res) {
    answer(req, res, [&] { return routes.page(); });
  };
  // Exact paths only: "/..", "/%2e%2e/", "//etc/passwd" and the like match nothing.
  server.Get("/", serve_page);
  server.Get("/index.html", serve_page);
  if (routes.truth) {
    server.Get("/truth", [&routes](const httplib::Request& req, httplib::Response& res) {
      answer(req, res, [&] { return routes.truth(req.params); });
    });
  }
  server.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
    if (res.status == 404) res.set_content("not found: hisnegs view serves / only\n", "text/plain");
    if (res.status != 500) std::fprintf(stderr, "view: %d %s %s\n", res.status, req.method.c_str(), req.path.c_str());
  });

  int port = options.port;
  if (port == 0) {
    port = server.bind_to_any_port(options.host.c_str());
  } else if (!server.bind_to_port(options.host.c_str(), port)) {
    port = -1;
  }
  if (port < 0) {
    throw io::InputError("view: cannot listen on " + options.host + ":" + std::to_string(options.port) +
                             " (in use, or not an address of this machine)");
  }
  const bool v6 = options.host.find(':') != std::string::npos;
  const std::string url =
      "http://" + (v6 ? "[" + options.host + "]" : options.host) + ":" + std::to_string(port) + "/";

  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("view: cannot create the signal pipe");
  g_signal_pipe = fds[1];
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;
  struct sigaction previous_int {}, previous_term {};
  sigaction(SIGINT, &action, &previous_int);
  sigaction(SIGTERM, &action, &previous_term);

  std::atomic<int> received{0};
  std::thread waiter([&] {
    unsigned char byte = 0;
    ssize_t n = 0;
    while ((n = ::read(fds[0], &byte, 1)) < 0 && errno == EINTR) {
    }
    received = n == 1 ? byte : 0;
    server.stop();
  });
  on_listening(url);
  server.listen_after_bind();
  if (received == 0) {  // stopped for another reason: wake the waiter with a 0 byte
    const unsigned char zero = 0;
    (void)!::write(fds[1], &zero, 1);
  }
  waiter.join();
  sigaction(SIGINT, &previous_int, nullptr);
  sigaction(SIGTERM, &previous_term, nullptr);
  g_signal_pipe = -1;
  ::close(fds[0]);
  ::close(fds[1]);
  return received;
}

}  // namespace hisnegs::apps
