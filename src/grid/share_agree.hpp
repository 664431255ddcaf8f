// The moves every shared step makes between processes (select_shares.hpp: the selection;
// brick_shares.hpp: regions sent by process 0): a combination at process 0 broadcast back, and
// checks agreed before anything is sent that only a process going on would receive. Internal.
#pragma once
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <exception>
#include <span>
#include <string>
#include <vector>

#include "adaptiso/error.hpp"
#include "adaptiso/select_shares.hpp"

namespace adaptiso::detail::share {

// Where process q's part begins when n items are split among P processes in order, as evenly as
// can be (the first n % P parts one longer): q's part is [part_begin(n, P, q), part_begin(n, P, q + 1)).
constexpr std::uint64_t part_begin(std::uint64_t n, std::uint64_t P, std::uint64_t q) { return n / P * q + std::min(q, n % P); }

template <class T>
std::span<std::byte> bytes(std::vector<T>& v) {
  return std::as_writable_bytes(std::span(v));
}

// `values` combined over the processes, on every process: the others' sent to process 0, which
// folds each into its own in process order (combine(own, theirs)), then broadcasts the result.
template <class T, class Combine>
void combine_at_zero(ShareTransport& t, std::span<T> values, Combine combine) {
  if (t.process() != 0) {
    t.send(std::as_bytes(values));
  } else {
    std::vector<T> theirs(values.size());
    for (int p = 1; p < t.processes(); ++p) {
      t.receive(p, std::as_writable_bytes(std::span(theirs)));
      for (std::size_t i = 0; i < values.size(); ++i) combine(values[i], theirs[i]);
    }
  }
  t.broadcast(std::as_writable_bytes(values));
}

// Each process's checks, agreed before anything is sent that only a process going on would
// receive: a process whose check failed rethrows its error once the others know, and they throw an
// InputError naming the first such process and `step`.
inline void agree(ShareTransport& t, const std::exception_ptr& failed, const char* step = "the selection") {
  std::int64_t first = failed ? t.process() : -1;
  combine_at_zero(t, std::span(&first, 1), [](std::int64_t& own, std::int64_t theirs) {
    if (own < 0) own = theirs;
  });
  if (failed) std::rethrow_exception(failed);
  if (first >= 0) throw InputError(fmt::format("process {} cannot take its share of {} (its own message says why)", first, step));
}

// Each process's failure of a step every process takes (a shared load's opening and header, before
// the processes can compare what they read): if any failed, every process throws an InputError
// with the first such process's message, naming it ("… (process 2)"), so that none waits for a
// process that will not come; unlike agree, the message itself reaches them all. `failed`: this
// process's InputError, or nullptr.
inline void agree_first_failure(ShareTransport& t, const std::exception_ptr& failed) {
  std::int64_t first = failed ? t.process() : -1;
  combine_at_zero(t, std::span(&first, 1), [](std::int64_t& own, std::int64_t theirs) {
    if (own < 0) own = theirs;  // folded in process order: the first that failed
  });
  if (first < 0) return;
  std::string message;
  if (t.process() == first) try {
      std::rethrow_exception(failed);
    } catch (const std::exception& e) {
      message = e.what();
    }
  std::uint64_t length = message.size();
  if (first != 0 && t.process() == first) {
    t.send(std::as_bytes(std::span(&length, 1)));
    t.send(std::as_bytes(std::span(message.data(), message.size())));
  } else if (first != 0 && t.process() == 0) {
    t.receive(static_cast<int>(first), std::as_writable_bytes(std::span(&length, 1)));
    message.resize(length);
    t.receive(static_cast<int>(first), std::as_writable_bytes(std::span(message.data(), message.size())));
  }
  t.broadcast(std::as_writable_bytes(std::span(&length, 1)));
  message.resize(length);
  t.broadcast(std::as_writable_bytes(std::span(message.data(), message.size())));
  throw InputError(first == 0 ? message : fmt::format("{} (process {})", message, first));
}

// Whether `words` differ from process 0's, which they are then (broadcast from it). Collective.
template <class T, std::size_t N>
bool differs_from_zero(ShareTransport& t, std::array<T, N>& words) {
  const std::array<T, N> mine = words;
  t.broadcast(std::as_writable_bytes(std::span(words)));
  return words != mine;
}

// A vector of any length from this process (not 0) to process 0, which takes it with
// receive_vector: its length, then its elements.
template <class T>
void send_vector(ShareTransport& t, const std::vector<T>& v) {
  const std::uint64_t n = v.size();
  t.send(std::as_bytes(std::span(&n, 1)));
  t.send(std::as_bytes(std::span(v)));
}
template <class T>
std::vector<T> receive_vector(ShareTransport& t, int from) {
  std::uint64_t n = 0;
  t.receive(from, std::as_writable_bytes(std::span(&n, 1)));
  std::vector<T> v(n);
  t.receive(from, std::as_writable_bytes(std::span(v)));
  return v;
}
// Process 0's vector, of any length, on every process.
template <class T>
void broadcast_vector(ShareTransport& t, std::vector<T>& v) {
  std::uint64_t n = v.size();
  t.broadcast(std::as_writable_bytes(std::span(&n, 1)));
  if (t.process() != 0) v.resize(n);
  t.broadcast(std::as_writable_bytes(std::span(v)));
}

}  // namespace adaptiso::detail::share
