// Memory estimates against what the machine has (see memory.hpp).
#include "util/memory.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>

#include "adaptiso/error.hpp"

namespace adaptiso::detail {

std::uint64_t available_memory() {
  // A cap a user (or a test) sets for adaptiso, in bytes: a shared machine, a container.
  if (const char* cap = std::getenv("ADAPTISO_MEMORY_LIMIT")) {
    char* end = nullptr;
    const unsigned long long v = std::strtoull(cap, &end, 10);
    if (end != cap && *end == '\0') return v;
  }
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

namespace {

std::string bytes_text(std::uint64_t b) {
  const double x = static_cast<double>(b);
  return x >= 1e9 ? fmt::format("{:.1f} GB", x / 1e9) : fmt::format("{:.0f} MB", x / 1e6);
}

}  // namespace

std::string duration_text(double seconds) {
  if (seconds < 120) return fmt::format("{:.0f} s", std::max(seconds, 1.0));
  if (seconds < 7200) return fmt::format("{:.0f} min", seconds / 60);
  return fmt::format("{:.1f} h", seconds / 3600);
}

void check_memory(std::uint64_t bytes, const std::string& what, const std::string& option, const std::string& advice) {
  const std::uint64_t available = available_memory();
  if (bytes <= available) return;
  const std::string text = fmt::format("{} needs about {}, {} are available; {}", what, bytes_text(bytes), bytes_text(available), advice);
  if (option.empty()) throw InputError(text);
  throw OptionError(option, text);
}

}  // namespace adaptiso::detail
