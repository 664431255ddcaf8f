// Memory estimates against what the machine has (see memory.hpp).
#include "util/memory.hpp"

#include <fmt/format.h>
#include <sys/resource.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <fstream>

#include "adaptiso/error.hpp"
#include "adaptiso/memory.hpp"

namespace adaptiso::detail {

std::uint64_t process_status_bytes(const std::string& field) {
  std::ifstream status("/proc/self/status");
  const std::string key = field + ":";
  for (std::string line; std::getline(status, line);)
    if (line.rfind(key, 0) == 0) return std::strtoull(line.c_str() + key.size(), nullptr, 10) * 1024;
  return 0;
}

void release_free_heap() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
}

namespace {

// The address space left under `ulimit -v` (RLIMIT_AS): a cap the machine's free memory knows
// nothing of, and the one a container or a careful user sets.
std::uint64_t address_space_left() {
  struct rlimit lim {};
  if (getrlimit(RLIMIT_AS, &lim) != 0 || lim.rlim_cur == RLIM_INFINITY) return ~std::uint64_t{0};
  const std::uint64_t used = process_status_bytes("VmSize");
  return lim.rlim_cur > used ? lim.rlim_cur - used : 0;
}

std::uint64_t system_memory() {
  std::ifstream meminfo("/proc/meminfo");
  for (std::string key; meminfo >> key;) {
    std::uint64_t kb = 0;
    meminfo >> kb;
    if (key == "MemAvailable:") return kb * 1024;
    meminfo.ignore(256, '\n');
  }
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(page) : ~std::uint64_t{0};
}

}  // namespace

namespace {

std::atomic<std::uint64_t> g_memory_limit{0};  // set_memory_limit's; 0: none

// What the machine gives now, the limit, and what is available under both.
struct MemoryNow {
  std::uint64_t machine = 0, limit = 0, available = 0;
};
MemoryNow memory_now() {
  MemoryNow m;
  m.machine = m.available = std::min(system_memory(), address_space_left());
  m.limit = adaptiso::memory_limit();
  if (m.limit > 0) {
    const std::uint64_t held = process_status_bytes("VmRSS");
    m.available = std::min(m.available, m.limit > held ? m.limit - held : 0);
  }
  return m;
}

}  // namespace

std::uint64_t available_memory() { return memory_now().available; }

namespace {

// Three significant digits at most: an estimate from absurd counts must not print 20 of them.
std::string bytes_text(std::uint64_t b) {
  const double x = static_cast<double>(b);
  if (x >= 1e9) return fmt::format("{:.3g} GB", x / 1e9);
  return x >= 1e6 ? fmt::format("{:.0f} MB", x / 1e6) : fmt::format("{:.0f} kB", x / 1e3);
}

}  // namespace

std::string duration_text(double seconds) {
  if (seconds < 120) return fmt::format("{:.0f} s", std::max(seconds, 1.0));
  if (seconds < 7200) return fmt::format("{:.0f} min", seconds / 60);
  return fmt::format("{:.3g} h", seconds / 3600);  // not 300 digits for an absurd estimate
}

void check_memory(std::uint64_t bytes, const std::string& what, const std::string& option, const std::string& advice) {
  const MemoryNow m = memory_now();
  if (bytes <= m.available) return;
  const bool limited = m.limit > 0 && m.available < m.machine;
  const std::string left = limited ? fmt::format("the memory limit of {} leaves {}", bytes_text(m.limit), bytes_text(m.available))
                                   : fmt::format("{} are available", bytes_text(m.available));
  const std::string text = fmt::format("{} needs about {}, {}; {}", what, bytes_text(bytes), left, advice);
  if (option.empty()) throw InputError(text);
  throw OptionError(option, text);
}

}  // namespace adaptiso::detail

namespace adaptiso {

void set_memory_limit(std::uint64_t bytes) { detail::g_memory_limit = bytes; }

std::uint64_t memory_limit() {
  if (const std::uint64_t set = detail::g_memory_limit) return set;
  // The same limit from the environment, in bytes: a shared machine, a container, a test.
  if (const char* cap = std::getenv("ADAPTISO_MEMORY_LIMIT")) {
    char* end = nullptr;
    const unsigned long long v = std::strtoull(cap, &end, 10);
    if (end != cap && *end == '\0') return v;
  }
  return 0;
}

void require_memory(std::uint64_t bytes, const std::string& what, const std::string& option, const std::string& advice) {
  detail::check_memory(bytes, what, option, advice);
}

std::uint64_t peak_resident_bytes() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<std::uint64_t>(u.ru_maxrss) * 1024;  // Linux: kilobytes
}

}  // namespace adaptiso
