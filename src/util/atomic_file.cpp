#include "adaptiso/atomic_file.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>

#include "adaptiso/error.hpp"

namespace adaptiso {
namespace {
namespace fs = std::filesystem;

// Temporary files being written, so a signal that would kill the process removes them first.
// Plain C strings in atomics: the handler may only read memory and call unlink.
constexpr std::size_t kSlots = 64;
std::array<std::atomic<const char*>, kSlots> in_flight{};

extern "C" void remove_temporaries_and_die(int sig) {
  for (auto& slot : in_flight)
    if (const char* p = slot.load()) ::unlink(p);
  std::signal(sig, SIG_DFL);
  std::raise(sig);
}

// Only where the signal would kill the process anyway: a host (Python, a viewer with its own
// handler) that catches SIGINT keeps its handler and gets the exception path instead.
void install_cleanup_handlers() {
  static std::once_flag once;
  std::call_once(once, [] {
    for (int sig : {SIGINT, SIGTERM, SIGHUP}) {
      struct sigaction old {};
      if (sigaction(sig, nullptr, &old) != 0 || old.sa_handler != SIG_DFL || (old.sa_flags & SA_SIGINFO)) continue;
      struct sigaction sa {};
      sa.sa_handler = remove_temporaries_and_die;
      sigemptyset(&sa.sa_mask);
      sigaction(sig, &sa, nullptr);
    }
  });
}

class InFlight {
public:
  explicit InFlight(std::string path) : path_(std::move(path)) {
    for (auto& s : in_flight) {
      const char* expected = nullptr;
      if (s.compare_exchange_strong(expected, path_.c_str())) {
        slot_ = &s;
        return;
      }
    }
  }
  ~InFlight() {
    if (slot_) slot_->store(nullptr);
  }
  InFlight(const InFlight&) = delete;
  InFlight& operator=(const InFlight&) = delete;

private:
  std::string path_;
  std::atomic<const char*>* slot_ = nullptr;
};

// Where the bytes must land: through a symlink to its target, and only ever over a regular file
// (renaming over /dev/null or a FIFO would replace the device, not write to it).
fs::path resolve_target(const std::string& path) {
  std::error_code ec;
  fs::path target(path);
  if (fs::is_symlink(fs::symlink_status(target, ec))) {
    fs::path resolved = fs::weakly_canonical(target, ec);
    if (ec) throw InputError(fmt::format("{}: cannot follow the symbolic link ({})", path, ec.message()));
    target = resolved;
  }
  auto st = fs::status(target, ec);
  if (fs::exists(st) && !fs::is_regular_file(st))
    throw InputError(fmt::format("{}: exists and is not a regular file (a folder, device or FIFO); adaptiso will not replace it", path));
  return target;
}

void sync_file(const fs::path& p, const std::string& path) {
  int fd = ::open(p.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(fmt::format("{}: cannot reopen the written file ({})", path, std::strerror(errno)));
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) throw InputError(fmt::format("{}: cannot flush the file to disk ({})", path, std::strerror(err)));
}

void sync_folder(const fs::path& dir) {
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;  // the rename has happened; a folder we cannot open cannot be synced either
  ::fsync(fd);
  ::close(fd);
}

void write_and_rename(const std::string& path, const std::function<void(std::ostream&)>& write) {
  const fs::path target = resolve_target(path);
  const fs::path dir = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw InputError(fmt::format("{}: folder {} does not exist", path, dir.string()));
  struct stat old {};
  const bool replacing = ::stat(target.c_str(), &old) == 0;

  std::random_device rd;
  const fs::path tmp = dir / fmt::format(".{}.tmp{}{:x}", target.filename().string(), getpid(), rd());
  install_cleanup_handlers();
  InFlight guard(tmp.string());
  try {
    {
      std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
      if (!out) throw InputError(fmt::format("{}: cannot write ({})", path, std::strerror(errno)));
      write(out);
      out.flush();
      if (!out) throw InputError(fmt::format("{}: write failed (disk full?)", path));
    }
    // The replaced file keeps its permissions (a private 0600 result stays private).
    if (replacing) ::chmod(tmp.c_str(), old.st_mode & 07777);
    // On disk before the rename, so a machine crash cannot leave an empty file under the final name.
    sync_file(tmp, path);
    fs::rename(tmp, target, ec);
    if (ec) throw InputError(fmt::format("{}: cannot rename the finished file into place: {}", path, ec.message()));
    sync_folder(dir);
  } catch (...) {
    fs::remove(tmp, ec);
    throw;
  }
}

}  // namespace

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write) {
  try {
    write_and_rename(path, write);
  } catch (const fs::filesystem_error& e) {
    // Paths the system refuses (too long, not a folder on the way): the user's input, not our bug.
    throw InputError(fmt::format("{}: cannot write ({})", path, e.code().message()));
  }
}

}  // namespace adaptiso
