// SPDX-License-Identifier: Apache-2.0
// `hisnegs view`'s local HTTP server (cpp-httplib): the viewer page at "/" (and
// "/index.html"), optionally the ground-truth MIP at "/truth", and nothing else,
// until SIGINT/SIGTERM. Knows nothing of models or cameras: the routes are
// functions (viewer_session.hpp provides them).
#pragma once

#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace hisnegs::apps {

struct ViewerServerOptions {
  std::string host = "127.0.0.1";  // address to bind; loopback unless told otherwise
  int port = 8080;                 // TCP port, [0, 65535]; 0 = any free port
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

// Binds, calls `on_listening(url)` with the page's URL (http://HOST:PORT/), serves
// `routes` until SIGINT or SIGTERM arrives, then stops cleanly and returns the signal
// number. A route that throws answers 500 with the exception's text (one line on
// stderr, "view: 500 GET /path: WHAT"); the server keeps running. Every other path
// (traversal, encoded or absolute forms included) gets 404; methods other than
// GET/HEAD get 405. Handles SIGINT/SIGTERM while it runs (the previous handlers
// come back after). Throws io::InputError for a port out of range or an address
// that cannot be bound.
int serve_viewer(const ViewerRoutes& routes, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening);

// Whether `host` is a loopback address (127.0.0.0/8, ::1, localhost).
[[nodiscard]] bool is_loopback_host(const std::string& host);

}  // namespace hisnegs::apps
