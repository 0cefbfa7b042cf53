// SPDX-License-Identifier: Apache-2.0
// The viewer's HTTP server on cpp-httplib (Debian libcpp-httplib-dev, a shared
// library whose limits are compiled in): httplib parses requests and routes them;
// this file owns the connections. GuardedServer overrides httplib's per-connection
// loop (Server::process_and_close_socket) to serve each socket through a
// ClientStream that enforces ViewerServerLimits (bytes, header lines and time per
// request; time per read and write) and to count connections per client, and keeps
// every open socket so that a stop can shut them all down. Clean shutdown on
// SIGINT/SIGTERM whichever thread receives it: the handler only writes the signal
// number into a pipe, and a waiter thread reading it stops the server.
#include "apps/viewer/viewer_server.hpp"

#include <httplib.h>
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>

#include "io/error.hpp"

namespace hisnegs::apps {

bool is_loopback_host(const std::string& host) {
  return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

namespace {

using Clock = std::chrono::steady_clock;

// The write end of the running server's signal pipe (one server per process at a time).
std::atomic<int> g_signal_pipe{-1};

extern "C" void on_stop_signal(int sig) {
  const unsigned char byte = static_cast<unsigned char>(sig);
  const int fd = g_signal_pipe.load();
  if (fd >= 0) (void)!::write(fd, &byte, 1);  // async-signal-safe
}

// One stderr line of the server, every client-sent part through io::printable.
template <class... Args>
void log_line(const char* format, Args... args) {
  std::fprintf(stderr, format, args...);
  std::fflush(stderr);
}

// Lines about limits a client hit: at most one a second (a flood of connections
// must not become a flood of lines), with how many were left out.
void log_limit(const std::string& client, const std::string& what) {
  static std::mutex mutex;
  static Clock::time_point last{};
  static int skipped = 0;
  const std::lock_guard lock(mutex);
  const Clock::time_point now = Clock::now();
  if (now - last < std::chrono::seconds(1)) {
    ++skipped;
    return;
  }
  last = now;
  const std::string more = skipped > 0 ? " (and " + std::to_string(skipped) + " such events before)" : "";
  skipped = 0;
  log_line("view: %s: %s%s\n", io::printable(client, 64).c_str(), what.c_str(), more.c_str());
}

int milliseconds(double seconds) { return static_cast<int>(std::clamp(seconds * 1e3, 0.0, 3.6e6)); }

// The remote address of a connected socket ("127.0.0.1", "::1"), "" if unknown.
std::string peer_address(int sock) {
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  if (::getpeername(sock, reinterpret_cast<sockaddr*>(&addr), &len) != 0) return "";
  char text[INET6_ADDRSTRLEN] = {};
  const void* raw = addr.ss_family == AF_INET6 ? static_cast<const void*>(&reinterpret_cast<sockaddr_in6&>(addr).sin6_addr)
                                               : static_cast<const void*>(&reinterpret_cast<sockaddr_in&>(addr).sin_addr);
  return ::inet_ntop(addr.ss_family, raw, text, sizeof text) ? text : "";
}

int port_of(const sockaddr_storage& addr) {
  return ntohs(addr.ss_family == AF_INET6 ? reinterpret_cast<const sockaddr_in6&>(addr).sin6_port
                                          : reinterpret_cast<const sockaddr_in&>(addr).sin_port);
}

// The open client sockets and how many each remote address holds.
class ConnectionTable {
 public:
  enum class Opened { kYes, kClientFull, kServerFull };
  // Registers `sock` unless `client` holds `per_client` connections already or the
  // server holds `total` (nothing registered then).
  Opened open(int sock, const std::string& client, int per_client, int total) {
    const std::lock_guard lock(mutex_);
    if (static_cast<int>(sockets_.size()) >= total) return Opened::kServerFull;
    int& held = per_client_[client];
    if (held >= per_client) {
      if (held == 0) per_client_.erase(client);
      return Opened::kClientFull;
    }
    ++held;
    sockets_.insert(sock);
    return Opened::kYes;
  }
  void close(int sock, const std::string& client) {
    const std::lock_guard lock(mutex_);
    sockets_.erase(sock);
    if (--per_client_[client] <= 0) per_client_.erase(client);
  }
  // Every blocked read or write on an open connection returns at once.
  void shut_all() {
    const std::lock_guard lock(mutex_);
    for (const int sock : sockets_) ::shutdown(sock, SHUT_RDWR);
  }

 private:
  std::mutex mutex_;
  std::set<int> sockets_;
  std::map<std::string, int> per_client_;
};

// One client connection as httplib reads and writes it, within the limits: per
// request at most max_request_bytes and max_header_lines read, all of them within
// head_timeout_s, each read and write waiting at most io_timeout_s, the response
// written within head_timeout_s + 30 s. Fails every call once the server stops.
class ClientStream final : public httplib::Stream {
 public:
  ClientStream(int sock, const ViewerServerLimits& limits, const std::atomic<bool>& stopping)
      : sock_(sock), limits_(limits), stopping_(stopping) {}

  // A new request begins: its budget and deadlines start now.
  void start_request() {
    bytes_ = 0;
    lines_ = 0;
    tripped_.clear();
    const Clock::time_point now = Clock::now();
    head_deadline_ = now + std::chrono::milliseconds(milliseconds(limits_.head_timeout_s));
    write_deadline_ = head_deadline_ + std::chrono::seconds(kResponseSeconds);
  }
  // Waits up to `seconds` for the next request's first byte (keep-alive).
  bool wait_for_request(double seconds) {
    return pos_ < end_ || (!stopping_ && wait(POLLIN, milliseconds(seconds)) > 0);
  }
  // Which limit cut the request off ("" if none).
  [[nodiscard]] const std::string& tripped() const { return tripped_; }

  bool is_readable() const override {
    return pos_ < end_ || (!stopping_ && wait(POLLIN, milliseconds(limits_.io_timeout_s)) > 0);
  }
  bool is_writable() const override { return !stopping_ && wait(POLLOUT, milliseconds(limits_.io_timeout_s)) > 0; }

  ssize_t read(char* ptr, std::size_t size) override {
    if (pos_ == end_ && !fill()) return -1;
    const std::size_t n = std::min(size, end_ - pos_);
    if (bytes_ + n > limits_.max_request_bytes) {
      return trip("request over " + std::to_string(limits_.max_request_bytes / 1024) + " KiB; connection closed");
    }
    std::memcpy(ptr, buffer_ + pos_, n);
    pos_ += n;
    bytes_ += n;
    lines_ += static_cast<int>(std::count(ptr, ptr + n, '\n'));
    if (lines_ > limits_.max_header_lines + 2) {  // + the request line and the blank line ending the head
      return trip("more than " + std::to_string(limits_.max_header_lines) + " header lines; connection closed");
    }
    return static_cast<ssize_t>(n);
  }

  ssize_t write(const char* ptr, std::size_t size) override {
    const double left = std::chrono::duration<double>(write_deadline_ - Clock::now()).count();
    if (stopping_ || left <= 0 ||
        wait(POLLOUT, milliseconds(std::min(left, limits_.io_timeout_s))) <= 0) {
      return -1;
    }
    const ssize_t n = ::send(sock_, ptr, size, MSG_NOSIGNAL);
    return n < 0 && errno == EINTR ? 0 : n;
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override {
    sockaddr_storage addr{};
    socklen_t len = sizeof addr;
    ip = peer_address(sock_);
    port = ::getpeername(sock_, reinterpret_cast<sockaddr*>(&addr), &len) == 0 ? port_of(addr) : 0;
  }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    sockaddr_storage addr{};
    socklen_t len = sizeof addr;
    ip.clear();
    port = ::getsockname(sock_, reinterpret_cast<sockaddr*>(&addr), &len) == 0 ? port_of(addr) : 0;
  }
  socket_t socket() const override { return sock_; }

 private:
  static constexpr int kResponseSeconds = 30;

  int wait(short events, int timeout_ms) const {
    pollfd p{sock_, events, 0};
    int r = 0;
    while ((r = ::poll(&p, 1, timeout_ms)) < 0 && errno == EINTR) {
    }
    return r > 0 && (p.revents & (events | POLLHUP | POLLERR)) ? r : 0;
  }

  ssize_t trip(std::string what) {
    if (tripped_.empty()) tripped_ = std::move(what);
    return -1;
  }

  // The next bytes from the socket, waiting no longer than the head deadline and
  // the read timeout allow.
  bool fill() {
    for (;;) {
      if (stopping_) return false;
      const double to_deadline = std::chrono::duration<double>(head_deadline_ - Clock::now()).count();
      if (to_deadline <= 0) {
        trip("request not complete within " + io::number_text(limits_.head_timeout_s) + " s; connection closed");
        return false;
      }
      const double wait_s = std::min(to_deadline, limits_.io_timeout_s);
      if (wait(POLLIN, milliseconds(wait_s)) <= 0) {
        if (stopping_) return false;
        if (wait_s < limits_.io_timeout_s) continue;  // the deadline: said on the next turn
        if (bytes_ > 0) trip("no data for " + io::number_text(limits_.io_timeout_s) + " s; connection closed");
        return false;
      }
      const ssize_t n = ::recv(sock_, buffer_, sizeof buffer_, 0);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return false;
      pos_ = 0;
      end_ = static_cast<std::size_t>(n);
      return true;
    }
  }

  int sock_;
  const ViewerServerLimits& limits_;
  const std::atomic<bool>& stopping_;
  char buffer_[4096];
  std::size_t pos_ = 0, end_ = 0;
  std::size_t bytes_ = 0;
  int lines_ = 0;
  std::string tripped_;
  Clock::time_point head_deadline_{}, write_deadline_{};
};

// httplib's server with hisnegs' connection handling (see the file comment).
class GuardedServer final : public httplib::Server {
 public:
  explicit GuardedServer(const ViewerServerLimits& limits) : limits_(limits) {
    // A worker per connection the table allows, and spare ones: a connection beyond
    // the limits is answered 503 at once, never queued behind connections that hold
    // their workers (slow clients from many addresses starved everyone else).
    const auto threads = static_cast<std::size_t>(std::max(limits.threads, limits.connections_total + 4));
    new_task_queue = [threads] { return new httplib::ThreadPool(threads); };
    // Exclusive: SO_REUSEADDR only (a restart right after a stop binds again), never
    // httplib's default SO_REUSEPORT, which let a second server share the port.
    set_socket_options([this](socket_t sock) {
      const int yes = 1;
      ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
      listening_ = sock;
    });
    set_payload_max_length(0);  // no route takes a body: one is answered 413
  }

  // Once bound: the kernel's queue of connections not yet accepted as long as the
  // system allows. httplib listens with a backlog of 5, and a burst of connections
  // (a browser opens 6 at once, a page of tiles more) beyond it had its SYNs dropped
  // and waited 1-3 s for the retransmission. Linux takes a second listen() on a
  // listening socket as a new backlog.
  void widen_backlog() const {
    if (listening_ >= 0) (void)::listen(listening_, SOMAXCONN);
  }

  // Stops accepting, and shuts every open connection down so that no worker stays
  // blocked on a client.
  void begin_stop() {
    stopping_ = true;
    table_.shut_all();
    stop();
  }

 private:
  bool process_and_close_socket(socket_t sock) override {
    const std::string client = peer_address(sock);
    if (stopping_) {
      ::close(sock);
      return true;
    }
    const ConnectionTable::Opened opened =
        table_.open(sock, client, limits_.connections_per_client, limits_.connections_total);
    if (opened != ConnectionTable::Opened::kYes) {
      const bool client_full = opened == ConnectionTable::Opened::kClientFull;
      const std::string body = client_full ? "too many connections from this address; retry\n"
                                           : "too many connections to this server; retry\n";
      const std::string reply =
          "HTTP/1.1 503 Service Unavailable\r\nConnection: close\r\nRetry-After: 1\r\nContent-Type: text/plain\r\n"
          "Content-Length: " + std::to_string(body.size()) + "\r\n\r\n" + body;
      (void)!::send(sock, reply.data(), reply.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      log_limit(client, client_full ? "more than " + std::to_string(limits_.connections_per_client) +
                                          " connections at once; answered 503"
                                    : "the server holds " + std::to_string(limits_.connections_total) +
                                          " connections (every address together); answered 503");
      ::shutdown(sock, SHUT_RDWR);
      ::close(sock);
      return true;
    }
    ClientStream stream(sock, limits_, stopping_);
    for (int n = 0; n < limits_.requests_per_connection && !stopping_; ++n) {
      if (n > 0 && !stream.wait_for_request(limits_.idle_timeout_s)) break;
      stream.start_request();
      bool closed = false;
      const bool ok = process_request(stream, n + 1 == limits_.requests_per_connection, closed,
                                      [](httplib::Request&) {});
      if (!stream.tripped().empty()) log_limit(client, stream.tripped());
      if (!ok || closed || !stream.tripped().empty()) break;
    }
    table_.close(sock, client);
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
    return true;
  }

  const ViewerServerLimits limits_;
  std::atomic<bool> stopping_{false};
  ConnectionTable table_;
  socket_t listening_ = -1;
};

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
    log_line("view: 500 %s %s: %s\n", io::printable(req.method, 16).c_str(), io::printable(req.path, 200).c_str(),
             io::printable(e.what()).c_str());
    res.status = 500;
    res.set_content(std::string(e.what()) + "\n", "text/plain; charset=utf-8");
  }
}

void check_options(const ViewerServerOptions& options) {
  if (options.host.empty()) throw io::InputError("--host: empty address (e.g. 127.0.0.1, or 0.0.0.0 for every one)");
  if (options.port < 0 || options.port > 65535) {
    throw io::InputError("--port = " + std::to_string(options.port) + ": must be in [0, 65535]");
  }
}

// Exact paths only: "/..", "/%2e%2e/", "//etc/passwd" and the like match nothing.
void add_routes(GuardedServer& server, const ViewerRoutes& routes) {
  const auto serve_page = [&routes](const httplib::Request& req, httplib::Response& res) {
    answer(req, res, [&] { return routes.page(); });
  };
  server.Get("/", serve_page);
  server.Get("/index.html", serve_page);
  if (routes.truth) {
    server.Get("/truth", [&routes](const httplib::Request& req, httplib::Response& res) {
      answer(req, res, [&] { return routes.truth(req.params); });
    });
  }
  server.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
    if (res.status == 404) res.set_content("not found: hisnegs view serves / only\n", "text/plain");
    if (res.status == 413) res.set_content("hisnegs view takes no request bodies\n", "text/plain");
    if (res.status != 500) {
      log_line("view: %d %s %s\n", res.status, io::printable(req.method, 16).c_str(),
               io::printable(req.path, 200).c_str());
    }
  });
}

// Binds the server to the host and port (0: any free one); returns its URL.
std::string bind_server(GuardedServer& server, const ViewerServerOptions& options) {
  int port = options.port;
  if (port == 0) {
    port = server.bind_to_any_port(options.host);
  } else if (!server.bind_to_port(options.host, port)) {
    port = -1;
  }
  if (port < 0) {
    throw io::InputError("view: cannot listen on " + io::printable(options.host, 200) + ":" +
                         std::to_string(options.port) + " (in use, or not an address of this machine)");
  }
  server.widen_backlog();
  const bool v6 = options.host.find(':') != std::string::npos;
  return "http://" + (v6 ? "[" + options.host + "]" : options.host) + ":" + std::to_string(port) + "/";
}

}  // namespace

int serve_viewer(const ViewerRoutes& routes, const ViewerServerOptions& options,
                 const std::function<void(const std::string& url)>& on_listening) {
  check_options(options);
  if (!routes.page) throw std::invalid_argument("serve_viewer: no page route");
  GuardedServer server(options.limits);
  add_routes(server, routes);
  const std::string url = bind_server(server, options);

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
  std::mutex done_mutex;
  std::condition_variable done_changed;
  bool done = false;
  std::thread waiter([&] {
    unsigned char byte = 0;
    ssize_t n = 0;
    while ((n = ::read(fds[0], &byte, 1)) < 0 && errno == EINTR) {
    }
    received = n == 1 ? byte : 0;
    server.begin_stop();
    if (received == 0) return;  // stopped for another reason: the server is already down
    // Whatever the clients or a long route do, the process ends within the grace time.
    std::unique_lock lock(done_mutex);
    if (!done_changed.wait_for(lock, std::chrono::milliseconds(milliseconds(options.limits.stop_grace_s)),
                               [&] { return done; })) {
      std::printf("view: stopped (%s; a request still running was cut off)\n",
                  received == SIGINT ? "Ctrl-C" : "signal");
      std::fflush(stdout);
      std::_Exit(0);
    }
  });
  on_listening(url);
  server.listen_after_bind();
  {
    const std::lock_guard lock(done_mutex);
    done = true;
  }
  done_changed.notify_all();
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
