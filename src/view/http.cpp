// The viewer's HTTP plumbing (see http.hpp).
#include "view/http.hpp"

#include <arpa/inet.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

namespace adaptiso::detail {

ElasticPool::ElasticPool(std::size_t max_threads, std::chrono::milliseconds idle, std::size_t keep)
    : max_(max_threads), keep_(keep), idle_timeout_(idle) {}

ElasticPool::~ElasticPool() { shutdown(); }

void ElasticPool::enqueue(std::function<void()> fn) {
  std::lock_guard lock(mutex_);
  reap();
  jobs_.push_back(std::move(fn));
  // An idle thread takes one job when it wakes; until then it still counts as idle, so compare
  // the queued jobs with the idle threads (checking idle_ == 0 left a burst of connections
  // queued behind one idle thread, which a slow client then held).
  if (jobs_.size() > idle_ && threads_.size() < max_) {
    // The thread finds its own entry to leave the list when it exits; it cannot look before this
    // assignment completes, since it needs mutex_ for that.
    const auto self = threads_.emplace(threads_.end());
    *self = std::thread([this, self] { work(self); });
  }
  ready_.notify_one();
}

void ElasticPool::shutdown() {
  std::list<std::thread> threads;
  std::vector<std::thread> exited;
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
    threads.swap(threads_);
    exited.swap(exited_);
  }
  ready_.notify_all();
  for (auto& t : threads) t.join();
  for (auto& t : exited) t.join();
}

std::size_t ElasticPool::threads() const {
  std::lock_guard lock(mutex_);
  return threads_.size();
}

void ElasticPool::reap() {
  for (auto& t : exited_) t.join();  // they released the mutex and are returning
  exited_.clear();
}

void ElasticPool::work(std::list<std::thread>::iterator self) {
  std::unique_lock lock(mutex_);
  for (;;) {
    ++idle_;
    const bool woke = ready_.wait_for(lock, idle_timeout_, [&] { return stop_ || !jobs_.empty(); });
    --idle_;
    if (stop_ && jobs_.empty()) return;  // shutdown() joins us from its own copy of the list
    if (!woke) {
      if (threads_.size() <= keep_) continue;
      exited_.push_back(std::move(*self));  // joined by the next enqueue (or shutdown)
      threads_.erase(self);
      return;
    }
    auto job = std::move(jobs_.front());
    jobs_.pop_front();
    lock.unlock();
    job();
    lock.lock();
  }
}

namespace {

// One connection's stream: its read buffer lives as long as the connection (see HttpServer).
// Reads and writes wait at most the server's timeouts, as httplib's SocketStream does.
class ConnectionStream final : public httplib::Stream {
public:
  ConnectionStream(int fd, int read_timeout_ms, int write_timeout_ms) : fd_(fd), read_ms_(read_timeout_ms), write_ms_(write_timeout_ms) {}

  bool is_readable() const override { return begin_ < end_ || wait(POLLIN, read_ms_); }
  bool is_writable() const override { return wait(POLLOUT, write_ms_); }

  ssize_t read(char* ptr, std::size_t size) override {
    if (begin_ == end_) {
      const ssize_t n = fill();
      if (n <= 0) return n;
    }
    const std::size_t k = std::min(size, end_ - begin_);
    std::memcpy(ptr, buffer_ + begin_, k);
    begin_ += k;
    return static_cast<ssize_t>(k);
  }

  ssize_t write(const char* ptr, std::size_t size) override {
    if (!wait(POLLOUT, write_ms_)) return -1;
    ssize_t n;
    do {
      n = ::send(fd_, ptr, size, MSG_NOSIGNAL);
    } while (n < 0 && errno == EINTR);
    return n;
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override { address(&getpeername, ip, port); }
  void get_local_ip_and_port(std::string& ip, int& port) const override { address(&getsockname, ip, port); }
  socket_t socket() const override { return fd_; }

  // Waits for the next request: true when bytes of it are buffered already (pipelined) or arrive
  // within `timeout`; checks every 50 ms whether the server is stopping.
  bool wait_for_request(std::chrono::milliseconds timeout, const std::atomic<socket_t>& listening) const {
    if (begin_ < end_) return true;
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (listening != INVALID_SOCKET) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now()).count();
      if (left <= 0) return false;
      if (wait(POLLIN, static_cast<int>(std::min<long long>(left, 50)))) return true;
      if (hung_up_) return false;
    }
    return false;
  }

  // Discards the next n bytes (a body no route reads); false when the connection ends first.
  bool skip(std::size_t n) {
    while (n > 0) {
      if (begin_ == end_ && fill() <= 0) return false;
      const std::size_t k = std::min(n, end_ - begin_);
      begin_ += k;
      n -= k;
    }
    return true;
  }

  // Closing with unread bytes in the socket makes the kernel reset the connection, and the client
  // may then lose the answer sent just before: say no more is sent, read what the client still
  // sends for a moment (at most 1 s and 1 MB), then close.
  void linger() {
    ::shutdown(fd_, SHUT_WR);
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(1);
    for (std::size_t drained = 0; drained < (std::size_t{1} << 20) && std::chrono::steady_clock::now() < until;) {
      if (!wait(POLLIN, 100)) continue;
      const ssize_t n = recv_some(buffer_, sizeof buffer_);
      if (n <= 0) return;
      drained += static_cast<std::size_t>(n);
    }
  }

private:
  bool wait(short events, int timeout_ms) const {
    pollfd p{fd_, events, 0};
    int r;
    do {
      r = ::poll(&p, 1, timeout_ms);
    } while (r < 0 && errno == EINTR);
    if (r > 0 && (p.revents & (POLLERR | POLLNVAL))) return false;
    if (r > 0 && (p.revents & POLLHUP) && !(p.revents & POLLIN)) {
      hung_up_ = true;
      return false;
    }
    return r > 0;
  }
  // Refills the empty buffer: the bytes read, 0 at the end of the connection, -1 on a timeout.
  ssize_t fill() {
    if (!wait(POLLIN, read_ms_)) return -1;
    const ssize_t n = recv_some(buffer_, sizeof buffer_);
    begin_ = 0;
    end_ = n > 0 ? static_cast<std::size_t>(n) : 0;
    return n;
  }
  ssize_t recv_some(char* to, std::size_t size) {
    ssize_t n;
    do {
      n = ::recv(fd_, to, size, 0);
    } while (n < 0 && errno == EINTR);
    return n;
  }
  void address(int (*get)(int, sockaddr*, socklen_t*), std::string& ip, int& port) const {
    sockaddr_storage a{};
    socklen_t len = sizeof a;
    ip.clear();
    port = 0;
    if (get(fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) return;
    char host[NI_MAXHOST] = {}, serv[NI_MAXSERV] = {};
    if (getnameinfo(reinterpret_cast<sockaddr*>(&a), len, host, sizeof host, serv, sizeof serv, NI_NUMERICHOST | NI_NUMERICSERV) != 0)
      return;
    ip = host;
    port = std::atoi(serv);
  }

  int fd_;
  int read_ms_, write_ms_;
  char buffer_[16384];
  std::size_t begin_ = 0, end_ = 0;
  mutable bool hung_up_ = false;
};

int milliseconds(time_t sec, time_t usec) { return static_cast<int>(std::min<long long>(sec * 1000LL + usec / 1000, 1 << 30)); }

// What remains of a request's body after its answer, none being read (see HttpServer).
struct Leftover {
  bool parsed = false;   // the request line and headers were understood
  bool unknown = false;  // chunked, or a length that is not a number: cannot be skipped
  std::size_t bytes = 0;
};

}  // namespace

bool HttpServer::process_and_close_socket(socket_t sock) {
  ConnectionStream stream(sock, milliseconds(read_timeout_sec_, read_timeout_usec_), milliseconds(write_timeout_sec_, write_timeout_usec_));
  bool ok = false;
  for (std::size_t left = keep_alive_max_count_; left > 0 && svr_sock_ != INVALID_SOCKET; --left) {
    if (!stream.wait_for_request(std::chrono::seconds(keep_alive_timeout_sec_), svr_sock_)) break;
    Leftover body;
    bool closing = false;
    ok = process_request(stream, left == 1, closing, [&](httplib::Request& req) {
      body.parsed = true;
      if (req.has_header("Transfer-Encoding")) {
        body.unknown = true;
      } else if (req.has_header("Content-Length")) {
        const std::string n = req.get_header_value("Content-Length");
        char* end = nullptr;
        errno = 0;
        const unsigned long long v = std::strtoull(n.c_str(), &end, 10);
        if (n.empty() || *end || errno || !std::isdigit(static_cast<unsigned char>(n[0])))
          body.unknown = true;
        else
          body.bytes = static_cast<std::size_t>(v);
      }
      // A body too large to skip: the answer says the connection closes (httplib writes
      // "Connection: close" when the request asked for it).
      if (body.unknown || body.bytes > max_skipped_body) {
        req.headers.erase("Connection");
        req.headers.emplace("Connection", "close");
      }
    });
    // A request httplib could not parse (400, 414) leaves the rest of its headers unread: the
    // stream cannot find the next request's start.
    if (ok && (!body.parsed || body.unknown || body.bytes > max_skipped_body)) {
      stream.linger();
      break;
    }
    if (!ok) break;
    if (closing) {
      if (body.bytes) stream.linger();
      break;
    }
    if (body.bytes && !stream.skip(body.bytes)) break;
  }
  ::shutdown(sock, SHUT_RDWR);
  ::close(sock);
  return ok;
}

std::string host_name(const std::string& header) {
  if (!header.empty() && header[0] == '[') return header.substr(0, header.find(']') + 1);
  return header.substr(0, header.find(':'));
}

bool is_ip_literal(const std::string& name) {
  if (name.size() > 2 && name.front() == '[' && name.back() == ']') return true;  // IPv6
  return !name.empty() &&
         std::all_of(name.begin(), name.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)) || c == '.'; });
}

namespace {

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

OriginVerdict check_origin(const std::string& origin, const std::string& fetch_site, const std::string& host,
                           const std::vector<std::string>& allowed) {
  const bool any = std::find(allowed.begin(), allowed.end(), "*") != allowed.end();
  if (!origin.empty()) {
    const std::string o = lower(origin);
    if (!host.empty() && o == "http://" + lower(host)) return OriginVerdict::same_origin;
    for (const auto& a : allowed)
      if (a == "*" || lower(a) == o) return OriginVerdict::allowed;
    return OriginVerdict::refused;
  }
  // No Origin: a browser's no-cors request (an <img>, a <script>) or not a browser at all.
  const std::string site = lower(fetch_site);
  if (site.empty() || site == "same-origin" || site == "none") return OriginVerdict::same_origin;
  return any ? OriginVerdict::allowed : OriginVerdict::refused;
}

}  // namespace adaptiso::detail
