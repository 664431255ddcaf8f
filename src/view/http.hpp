// Internal: the viewer's HTTP plumbing over cpp-httplib (0.11, Debian's shared library): the
// connections' thread pool, the keep-alive loop of a connection, and who may ask (the Host and
// Origin checks). Kept apart from the routes so each can be tested on its own.
#pragma once
#include <httplib.h>

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <list>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace adaptiso::detail {

// Connections are served by threads that are added while all are busy, up to a limit: a few
// clients that send their requests slowly (or hold their connection open) then cannot starve the
// others, as the fixed pool of 8 did (/api/info waited 17 s behind 8 clients sending a header
// line a second). A thread idle for `idle` exits, down to `keep` threads: 600 slow sockets left
// 184 threads behind for the life of the server (issue 41).
class ElasticPool : public httplib::TaskQueue {
public:
  ElasticPool(std::size_t max_threads, std::chrono::milliseconds idle, std::size_t keep);
  ~ElasticPool() override;
  void enqueue(std::function<void()> fn) override;
  void shutdown() override;
  std::size_t threads() const;  // alive now

private:
  void work(std::list<std::thread>::iterator self);
  void reap();  // joins the threads that exited (mutex_ held)
  const std::size_t max_, keep_;
  const std::chrono::milliseconds idle_timeout_;
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<std::function<void()>> jobs_;
  std::list<std::thread> threads_;
  std::vector<std::thread> exited_;
  std::size_t idle_ = 0;
  bool stop_ = false;
};

// httplib's server with its own keep-alive loop. httplib 0.11 reads each request through a stream
// made for that request alone, whose 4 kB buffer held the start of the next one when a client
// pipelined them; the buffer went with the stream, and the connection waited the keep-alive
// timeout (5 s) for bytes it had already read. Here one stream (and buffer) serves the whole
// connection, so pipelined requests are answered in turn. Bodies are never read by the routes
// (only GET and HEAD are served; other methods are answered 405 before routing): a body is
// skipped when its length is known and small, else the connection is closed after the answer.
class HttpServer : public httplib::Server {
public:
  std::size_t max_skipped_body = 1 << 16;

private:
  bool process_and_close_socket(socket_t sock) override;
};

// The host name of a Host header ("name", "name:port", "[v6]:port").
std::string host_name(const std::string& header);
bool is_ip_literal(const std::string& name);

// Whether a web page of another origin may use the API. Browsers send Origin with every
// cross-origin fetch (and Sec-Fetch-Site with every request): a request whose Origin is the
// server's own (http:// + its Host header) or one of `allowed` ("*": any) is served; a foreign
// Origin, or a cross-site or same-site (another port of the same host) Sec-Fetch-Site without an
// allowed Origin, is refused. Requests without either header (curl, scripts) are served.
enum class OriginVerdict { same_origin, allowed, refused };
OriginVerdict check_origin(const std::string& origin, const std::string& fetch_site, const std::string& host,
                           const std::vector<std::string>& allowed);

}  // namespace adaptiso::detail
