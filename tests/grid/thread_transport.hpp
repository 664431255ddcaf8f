// Processes played by threads of one test process (select_shares.hpp's ShareTransport): queues of
// messages between them, a message checked for the size its receiver expects.
#pragma once
#include <fmt/format.h>

#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

#include "adaptiso/select_shares.hpp"

namespace testutil {

using adaptiso::ShareTransport;

// Queues of messages between the threads that play the processes.
class Hub {
public:
  void push(int from, int to, std::vector<std::byte> bytes) {
    {
      std::lock_guard lock(m_);
      queues_[{from, to}].push_back(std::move(bytes));
    }
    cv_.notify_all();
  }
  std::vector<std::byte> pop(int from, int to) {
    std::unique_lock lock(m_);
    auto& q = queues_[{from, to}];
    if (!cv_.wait_for(lock, std::chrono::seconds(120), [&] { return !q.empty(); }))
      throw std::runtime_error(fmt::format("no message from {} to {}", from, to));
    std::vector<std::byte> bytes = std::move(q.front());
    q.pop_front();
    return bytes;
  }
  // Messages left unread: a protocol that sends what nobody receives.
  std::size_t left() {
    std::lock_guard lock(m_);
    std::size_t n = 0;
    for (const auto& [key, q] : queues_) n += q.size();
    return n;
  }

private:
  std::mutex m_;
  std::condition_variable cv_;
  std::map<std::pair<int, int>, std::deque<std::vector<std::byte>>> queues_;
};

class ThreadTransport final : public ShareTransport {
public:
  ThreadTransport(Hub& hub, int process, int processes) : hub_(hub), process_(process), processes_(processes) {}
  int process() const override { return process_; }
  int processes() const override { return processes_; }
  void broadcast(std::span<std::byte> bytes) override {
    if (process_ == 0) {
      for (int p = 1; p < processes_; ++p) hub_.push(0, p, {bytes.begin(), bytes.end()});
      return;
    }
    copy(hub_.pop(0, process_), bytes);
  }
  void send(std::span<const std::byte> bytes) override { hub_.push(process_, 0, {bytes.begin(), bytes.end()}); }
  void send_to(int to, std::span<const std::byte> bytes) override { hub_.push(process_, to, {bytes.begin(), bytes.end()}); }
  void receive(int from, std::span<std::byte> into) override { copy(hub_.pop(from, process_), into); }

private:
  static void copy(const std::vector<std::byte>& got, std::span<std::byte> into) {
    if (got.size() != into.size())
      throw std::runtime_error(fmt::format("a message of {} bytes where {} were expected", got.size(), into.size()));
    if (!got.empty()) std::memcpy(into.data(), got.data(), got.size());
  }
  Hub& hub_;
  int process_, processes_;
};

// `f(transport, p)` run by P threads playing processes 0 … P − 1 of one step; returns once all are done.
template <class F>
void as_processes(Hub& hub, int P, F&& f) {
  std::vector<std::thread> threads;
  for (int p = 0; p < P; ++p)
    threads.emplace_back([&, p] {
      ThreadTransport t(hub, p, P);
      f(t, p);
    });
  for (auto& th : threads) th.join();
}

}  // namespace testutil
