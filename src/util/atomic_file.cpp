#include "adaptiso/atomic_file.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include "adaptiso/error.hpp"

namespace adaptiso {

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write) {
  namespace fs = std::filesystem;
  fs::path target(path);
  fs::path dir = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  if (!fs::is_directory(dir)) throw InputError(fmt::format("{}: folder {} does not exist", path, dir.string()));
  std::random_device rd;
  fs::path tmp = dir / fmt::format(".{}.tmp{}{:x}", target.filename().string(), getpid(), rd());
  try {
    {
      std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
      if (!out) throw InputError(fmt::format("{}: cannot write ({})", path, std::strerror(errno)));
      write(out);
      out.flush();
      if (!out) throw InputError(fmt::format("{}: write failed (disk full?)", path));
    }
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) throw InputError(fmt::format("{}: cannot rename the finished file into place: {}", path, ec.message()));
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

}  // namespace adaptiso
