// SPDX-License-Identifier: Apache-2.0
// `hisnegs view`'s local HTTP server (cpp-httplib): the viewer page at "/" (and
// "/index.html"), optionally the ground-truth MIP at "/truth", and nothing else,
// until SIGINT/SIGTERM; with bounds on what any client can hold or send
// (ViewerServerLimits). Knows nothing of models or cameras: the routes are
// functions (viewer_session.hpp provides them).
#pragma once

#include <cstddef>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace hisnegs::apps {

// What one client (one remote address) can hold or send; docs/reliability.md "The
// viewer's server". Every bound is checked by the server itself, not by cpp-httplib's
// compiled-in defaults (Debian builds those into its shared library).
struct ViewerServerLimits {
  int connections_per_client = 6;   // open connections per remote address (a browser uses up to 6);
                                    // more are answered 503 and closed at once
  int connections_total = 48;       // open connections on the listening socket, whatever their
                                    // addresses (all of 127.0.0.0/8 is one machine); more: 503
  int threads = 52;                 // the worker pool: one per open connection allowed, and spare
                                    // ones that answer 503 at once (at least connections_total + 4)
  double head_timeout_s = 10.0;     // a request's line and headers must all arrive within this
  double io_timeout_s = 5.0;        // one read or write waits at most this
  double idle_timeout_s = 5.0;      // a kept-alive connection with no new request is closed after this
  int requests_per_connection = 100;
  std::size_t max_request_bytes = 64 * 1024;  // request line + headers (+ body), per request
  int max_header_lines = 100;                 // header lines per request
  double stop_grace_s = 1.5;  // after Ctrl-C, what is still running is cut off after this
};

struct ViewerServerOptions {
  std::string host = "127.0.0.1";  // address to bind; loopback unless told otherwise
  int port = 8080;                 // TCP port, [0, 65535]; 0 = any free port
  ViewerServerLimits limits;
};

// What a route answers.
struct ViewerReply {
  int status = 200;
  std::string content_type = "text/html; charset=utf-8";
  std::string body;
  std::vector<std::pair<std::string, std::string>> headers;  // extra response headers
};

// A request's query parameters (decoded), as cpp-httplib parses them.
using ViewerQuery = std::multimap<std::string, std::string>;

struct ViewerRoutes {
  std::function<ViewerReply()> page;                     // GET / and /index.html (required)
  std::function<ViewerReply(const ViewerQuery&)> truth;  // GET /truth; unset: 404
};

// Binds (exclusively: a second server on the same port fails, no SO_REUSEPORT), calls
// `on_listening(url)` with the page's URL (http://HOST:PORT/), serves `routes` until
// SIGINT or SIGTERM arrives, then stops within limits.stop_grace_s + ~0.2 s whatever
// the clients do (open connections are shut down; a route still running after the
// grace time is not waited for) and returns the signal number. A route that throws
// answers 500 with the exception's text (one line on stderr, "view: 500 GET /path:
// WHAT"); the server keeps running. Every other path (traversal, encoded or absolute
// forms included) gets 404; a request with a body gets 413; a request whose head is
// over the limits or too slow is cut off. Every line it logs goes through
// io::printable (no client-sent control characters reach the terminal). Handles
// SIGINT/SIGTERM while it runs (the previous handlers come back after). Throws
// io::InputError for an empty host, a port out of range or an address that cannot
// be bound.
int serve_viewer(const ViewerRoutes& routes, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening);

// Whether `host` is a loopback address (127.0.0.0/8, ::1, localhost).
[[nodiscard]] bool is_loopback_host(const std::string& host);

}  // namespace hisnegs::apps
