// SPDX-License-Identifier: Apache-2.0
// `hisnegs view`'s local HTTP server (cpp-httplib): serves one finished viewer page
// at "/" (and "/index.html") and nothing else, until SIGINT/SIGTERM. Knows nothing of
// models or cameras (viewer_page.hpp builds the page).
#pragma once

#include <functional>
#include <string>

namespace hisnegs::apps {

struct ViewerServerOptions {
  std::string host = "127.0.0.1";  // address to bind; loopback unless told otherwise
  int port = 8080;                 // TCP port, [0, 65535]; 0 = any free port
};

// Binds, calls `on_listening(url)` with the page's URL (http://HOST:PORT/), serves
// `page` until SIGINT or SIGTERM arrives, then stops cleanly and returns the signal
// number. Every other path (traversal, encoded or absolute forms included) gets 404;
// methods other than GET/HEAD get 405. Blocks SIGINT/SIGTERM in the calling thread
// (and so in the server's threads) while it runs. Throws io::InputError for a port out
// of range or an address that cannot be bound.
int serve_viewer(const std::string& page, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening);

// Whether `host` is a loopback address (127.0.0.0/8, ::1, localhost).
[[nodiscard]] bool is_loopback_host(const std::string& host);

}  // namespace hisnegs::apps
