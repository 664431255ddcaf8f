// Shared by the fuzz targets: each input is written to files in a private folder and read back
// through the same library call a user's file goes through. InputError is the expected answer to
// a bad file; anything else (a crash, an abort, another exception, a leak, a huge allocation, a
// hang) is a finding.
#pragma once
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>

#include "adaptiso/error.hpp"

namespace fuzz {

inline const std::filesystem::path& folder() {
  static const std::filesystem::path dir = [] {
    auto d = std::filesystem::temp_directory_path() / ("adaptiso-fuzz-" + std::to_string(getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

inline std::string write(const std::string& name, std::string_view bytes) {
  const std::string path = (folder() / name).string();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) __builtin_trap();
  if (!bytes.empty()) std::fwrite(bytes.data(), 1, bytes.size(), f);
  std::fclose(f);
  return path;
}

inline std::string_view as_view(const std::uint8_t* data, std::size_t size) { return {reinterpret_cast<const char*>(data), size}; }

// A header and its detached data in one input: the bytes before the first NUL are the header.
inline std::pair<std::string_view, std::string_view> split_at_nul(std::string_view in) {
  const auto nul = in.find('\0');
  if (nul == std::string_view::npos) return {in, {}};
  return {in.substr(0, nul), in.substr(nul + 1)};
}

template <class F>
void expect_input_error_or_success(F&& f) {
  try {
    f();
  } catch (const adaptiso::InputError&) {
  }
}

}  // namespace fuzz
