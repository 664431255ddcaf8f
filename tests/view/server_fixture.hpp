// What the viewer's server tests share (test_http.cpp, test_view_server.cpp): a server on a free
// loopback port in a background thread, and a raw connection for requests httplib's client would
// not send (slow headers, pipelining, malformed lines).
#pragma once
#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <thread>

#include "adaptiso/view_server.hpp"

namespace testutil {
using namespace adaptiso;

// Options for a test server: any free port, the page from the source tree.
inline ViewOptions server_options() {
  ViewOptions o;
  o.port = 0;
  o.web_dir = ADAPTISO_WEB_DIR;
  return o;
}

// A server listening in a background thread, stopped at scope exit. The constructor returns once
// /api/info answers (or after 2 s).
struct Running {
  ViewServer server;
  std::thread thread;
  int port = 0;
  explicit Running(ViewOptions o) : server(std::move(o)) {
    port = server.bind();
    thread = std::thread([this] { server.listen(); });
    httplib::Client c("127.0.0.1", port);
    for (int i = 0; i < 200 && !c.Get("/api/info"); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ~Running() {
    server.stop();
    thread.join();
  }
  httplib::Client client() const {
    httplib::Client c("127.0.0.1", port);
    c.set_read_timeout(30, 0);
    return c;
  }
};

// A raw loopback connection; reads time out after 3 s.
struct RawConnection {
  int fd = -1;
  explicit RawConnection(int port) {
    fd = socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) fd = -1;
    timeval tv{3, 0};
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  RawConnection(const RawConnection&) = delete;
  RawConnection& operator=(const RawConnection&) = delete;
  ~RawConnection() {
    if (fd >= 0) close(fd);
  }
  bool send_text(const std::string& s) const {
    return fd >= 0 && ::send(fd, s.data(), s.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(s.size());
  }
  // Everything until the server closes the connection (or 3 s of silence).
  std::string read_all() const {
    std::string got;
    char buf[65536];
    for (;;) {
      const ssize_t n = recv(fd, buf, sizeof buf, 0);
      if (n <= 0) return got;
      got.append(buf, static_cast<std::size_t>(n));
    }
  }
};

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace testutil
