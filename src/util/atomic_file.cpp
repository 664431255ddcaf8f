#include "adaptiso/atomic_file.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <ostream>
#include <random>
#include <streambuf>
#include <utility>
#include <vector>

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

// The file's bytes go to the disk directly (O_DIRECT) where the file system allows it, past the
// page cache: on this machine a 1.8 GB grid took 4.4 s to write through the cache and 4.6 s with
// the fsync, against 1.1 s straight to the disk, the cache's first touch of fresh memory being the
// cost (as for big arrays, util/big_array.hpp). The caller fills one aligned buffer while a thread
// writes the other. The last partial block is written through the cache (O_DIRECT wants whole
// blocks); a file system that refuses O_DIRECT, at open or at any write, gets ordinary writes
// from there on. A flush writes the whole blocks buffered and gives both buffers back to the
// system, keeping the few bytes past the last block aside: a writer that pauses between parts
// (prepare_to_file builds the index between the grid and the index) holds 32 MiB less meanwhile.
class DirectFileBuf : public std::streambuf {
public:
  static constexpr std::size_t kBuffer = kAtomicFileBufferBytes / 2, kBlock = 4096;

  // Opens `p` with `flags` (and O_DIRECT where the file system takes it, unless
  // ADAPTISO_NO_DIRECT_IO is set: through the cache, for file systems where O_DIRECT misbehaves).
  DirectFileBuf(const fs::path& p, int flags) {
    const int direct = std::getenv("ADAPTISO_NO_DIRECT_IO") ? 0 : O_DIRECT;
    fd_ = ::open(p.c_str(), flags | O_CLOEXEC | direct, 0666);
    direct_ = fd_ >= 0 && direct;
    if (fd_ < 0 && errno == EINVAL && direct) fd_ = ::open(p.c_str(), flags | O_CLOEXEC, 0666);
    if (fd_ < 0) error_ = errno;
  }
  ~DirectFileBuf() override {
    if (pending_.valid()) pending_.wait();
    if (fd_ >= 0) ::close(fd_);
  }
  DirectFileBuf(const DirectFileBuf&) = delete;
  DirectFileBuf& operator=(const DirectFileBuf&) = delete;

  bool is_open() const { return fd_ >= 0; }
  int fd() const { return fd_; }
  int error() const { return error_; }
  // Writes what is buffered; 0, or the errno of the first failure. The file stays open (an unnamed
  // one must be linked from its descriptor).
  int finish() {
    if (error_ == 0) hand_over(false);
    settle();
    return error_;
  }
  int close() {
    if (fd_ >= 0 && ::close(std::exchange(fd_, -1)) != 0 && error_ == 0) error_ = errno;
    return error_;
  }

protected:
  int sync() override {
    if (error_ != 0) return -1;
    if (!current_) return 0;
    const std::size_t n = static_cast<std::size_t>(pptr() - pbase()), whole = n / kBlock * kBlock;
    settle();
    if (error_ == 0) error_ = write_all(current_.get(), whole);
    if (error_ != 0) return -1;
    tail_.assign(current_.get() + whole, current_.get() + n);
    current_.reset();
    spare_.reset();
    setp(nullptr, nullptr);
    return 0;
  }
  int_type overflow(int_type ch) override {
    if (error_ != 0 || !hand_over(true)) return traits_type::eof();
    if (!traits_type::eq_int_type(ch, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(ch);
      pbump(1);
    }
    return traits_type::not_eof(ch);
  }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    std::streamsize done = 0;
    while (done < n) {
      if (pptr() == epptr() && (error_ != 0 || !hand_over(true))) break;
      const auto k = std::min<std::streamsize>(n - done, epptr() - pptr());
      std::memcpy(pptr(), s + done, static_cast<std::size_t>(k));
      pbump(static_cast<int>(k));
      done += k;
    }
    return done;
  }

private:
  // Mapped, not from the heap: page aligned as O_DIRECT wants, and given back whole when freed
  // (glibc would keep a freed 16 MiB block in its heap once its mmap threshold has grown past it).
  struct Unmap {
    void operator()(char* p) const { ::munmap(p, kBuffer); }
  };
  using Buffer = std::unique_ptr<char, Unmap>;

  static Buffer allocate() {
    void* p = ::mmap(nullptr, kBuffer, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    return Buffer(static_cast<char*>(p));
  }
  // Waits for the write in flight and keeps its error.
  void settle() {
    if (!pending_.valid()) return;
    const int e = pending_.get();
    if (error_ == 0) error_ = e;
  }
  // Sends the filled part of the current buffer to the writer thread and, if more is to come,
  // gives the caller the other buffer; false after an error.
  bool hand_over(bool more) {
    if (current_) {
      const std::size_t n = static_cast<std::size_t>(pptr() - pbase());
      settle();
      if (error_ != 0) return false;
      pending_ = std::async(std::launch::async, [this, p = current_.get(), n, last = !more] { return write_out(p, n, last); });
      if (!more) return true;
      if (!spare_) spare_ = allocate();
      std::swap(current_, spare_);
    } else if (!more) {
      // The end after a flush (or of an empty file): what the flush kept aside.
      settle();
      if (error_ == 0 && !tail_.empty()) error_ = write_out(tail_.data(), tail_.size(), true);
      tail_.clear();
      return error_ == 0;
    } else {
      current_ = allocate();
    }
    setp(current_.get(), current_.get() + kBuffer);
    if (!tail_.empty()) {  // the bytes a flush kept aside lead the new buffer, so writes stay whole blocks
      std::memcpy(current_.get(), tail_.data(), tail_.size());
      pbump(static_cast<int>(tail_.size()));
      tail_.clear();
    }
    return true;
  }
  // Writes n bytes at the file's end: whole blocks directly, a last partial one (only at the end)
  // through the cache.
  int write_out(const char* p, std::size_t n, bool last) {
    const std::size_t whole = last ? n / kBlock * kBlock : n;
    if (const int e = write_all(p, whole)) return e;
    if (whole == n) return 0;
    if (direct_ && !drop_direct()) return errno;
    return write_all(p + whole, n - whole);
  }
  // A write refused with EINVAL under O_DIRECT (a file system that takes the flag only at open,
  // or the position left unaligned by a short write) goes on through the cache from where it is.
  int write_all(const char* p, std::size_t n) {
    while (n > 0) {
      const ssize_t k = ::write(fd_, p, n);
      if (k < 0) {
        if (errno == EINTR || (errno == EINVAL && direct_ && drop_direct())) continue;
        return errno;
      }
      p += k;
      n -= static_cast<std::size_t>(k);
    }
    return 0;
  }
  bool drop_direct() {
    const int flags = ::fcntl(fd_, F_GETFL);
    if (flags < 0 || ::fcntl(fd_, F_SETFL, flags & ~O_DIRECT) != 0) return false;
    direct_ = false;
    return true;
  }

  int fd_ = -1;
  bool direct_ = false;  // O_DIRECT is on
  int error_ = 0;
  Buffer current_, spare_;
  std::vector<char> tail_;  // after a flush: the bytes past its last whole block (< kBlock)
  std::future<int> pending_;
};

// Where the bytes must land: through a symlink to its target (which need not exist yet: a dangling
// link is written through and then points at the new file, rather than being replaced by it), and
// only ever over a regular file (renaming over /dev/null or a FIFO would replace the device, not
// write to it).
fs::path resolve_target(const std::string& path) {
  std::error_code ec;
  fs::path target(path);
  for (int hops = 0; fs::is_symlink(fs::symlink_status(target, ec)); ++hops) {
    if (hops == 40) throw InputError(fmt::format("{}: too many levels of symbolic links", path));
    const fs::path next = fs::read_symlink(target, ec);
    if (ec) throw InputError(fmt::format("{}: cannot follow the symbolic link ({})", path, ec.message()));
    target = next.is_absolute() ? next : target.parent_path() / next;
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

// The folder the target is written in, which must exist.
fs::path target_folder(const fs::path& target, const std::string& path) {
  const fs::path dir = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw InputError(fmt::format("{}: folder {} does not exist", path, dir.string()));
  return dir;
}

// Our temporary files' names: ".NAME.tmp<pid>-<random hex>" beside the target NAME.
std::string temporary_prefix(const fs::path& target) { return "." + target.filename().string() + ".tmp"; }

// Temporary files of ours for this target whose writer is gone (killed by SIGKILL or a power cut,
// where nothing could remove them): a process id that no longer exists. Only where unnamed files
// cannot be used, which a kill leaves nothing of.
void remove_stale_temporaries(const fs::path& dir, const fs::path& target) {
  const std::string prefix = temporary_prefix(target);
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.starts_with(prefix)) continue;
    const std::string rest = name.substr(prefix.size());
    const std::size_t dash = rest.find('-');
    if (dash == 0 || dash == std::string::npos || rest.find_first_not_of("0123456789") != dash ||
        rest.find_first_not_of("0123456789abcdef", dash + 1) != std::string::npos)
      continue;
    const long pid = std::strtol(rest.c_str(), nullptr, 10);
    if (pid > 0 && pid != getpid() && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
      std::error_code ignored;
      fs::remove(it->path(), ignored);
    }
  }
}

// Writes through `file` and flushes it; throws InputError naming path on any failure.
void fill(DirectFileBuf& file, const std::string& path, const std::function<void(std::ostream&)>& write) {
  if (!file.is_open()) throw InputError(fmt::format("{}: cannot write ({})", path, std::strerror(file.error())));
  std::ostream out(&file);
  write(out);
  out.flush();
  const int error = file.finish();
  if (error != 0) throw InputError(fmt::format("{}: write failed ({})", path, std::strerror(error)));
  if (!out) throw InputError(fmt::format("{}: write failed", path));
}

}  // namespace

// A file written in full beside its target, not yet in place (StagedFile).
struct StagedFile::State {
  std::string path;  // as given, for the messages
  fs::path target, dir, tmp;
  bool replacing = false;
  struct stat old {};
  // Where the file system has them (ext4, xfs, btrfs, tmpfs): an unnamed file in the target's
  // folder (O_TMPFILE), given a name only at commit. Nothing is visible while it is written or
  // staged, and a process killed meanwhile, even by SIGKILL, leaves nothing behind: the kernel
  // frees an unnamed file with its last descriptor. At commit it is linked under a temporary name
  // and renamed over the target (linkat cannot replace a file), a window of two system calls.
  // ADAPTISO_NO_TMPFILE=1 uses a named temporary file throughout, as on file systems without them.
  std::unique_ptr<DirectFileBuf> unnamed;
  std::unique_ptr<InFlight> guard;  // from naming: SIGINT, SIGTERM and SIGHUP remove the temporary name
  bool named = false;

  void remove_named() {
    std::error_code ec;
    if (named) fs::remove(tmp, ec);
    named = false;
  }
};

namespace {

std::unique_ptr<StagedFile::State> stage_file(const std::string& path, const std::function<void(std::ostream&)>& write) {
  auto st = std::make_unique<StagedFile::State>();
  st->path = path;
  st->target = resolve_target(path);
  st->dir = target_folder(st->target, path);
  st->replacing = ::stat(st->target.c_str(), &st->old) == 0;
  std::random_device rd;
  st->tmp = st->dir / fmt::format("{}{}-{:x}", temporary_prefix(st->target), getpid(), rd());
  install_cleanup_handlers();
  if (!std::getenv("ADAPTISO_NO_TMPFILE")) {
    st->unnamed = std::make_unique<DirectFileBuf>(st->dir, O_TMPFILE | O_WRONLY);
    // Linked through /proc (linkat's AT_EMPTY_PATH would need a capability): without /proc the
    // unnamed file could never be named, so it is not used.
    if (!st->unnamed->is_open() || ::access(fmt::format("/proc/self/fd/{}", st->unnamed->fd()).c_str(), F_OK) != 0) st->unnamed.reset();
  }
  if (!st->unnamed) remove_stale_temporaries(st->dir, st->target);
  st->guard = std::make_unique<InFlight>(st->tmp.string());
  try {
    if (st->unnamed) {
      fill(*st->unnamed, path, write);
      // The replaced file keeps its permissions (a private 0600 result stays private); a new one
      // gets 0666 less the umask, as open gave it.
      if (st->replacing) ::fchmod(st->unnamed->fd(), st->old.st_mode & 07777);
      // On disk before it gets a name, so a machine crash cannot leave an empty file under the final name.
      if (::fsync(st->unnamed->fd()) != 0)
        throw InputError(fmt::format("{}: cannot flush the file to disk ({})", path, std::strerror(errno)));
    } else {
      st->named = true;
      {
        DirectFileBuf file(st->tmp, O_WRONLY | O_CREAT | O_TRUNC);
        fill(file, path, write);
        if (file.close() != 0) throw InputError(fmt::format("{}: write failed ({})", path, std::strerror(file.error())));
      }
      if (st->replacing) ::chmod(st->tmp.c_str(), st->old.st_mode & 07777);
      sync_file(st->tmp, path);
    }
  } catch (...) {
    st->remove_named();
    throw;
  }
  return st;
}

void commit_file(StagedFile::State& st) {
  const std::string& path = st.path;
  try {
    if (st.unnamed) {
      const std::string from = fmt::format("/proc/self/fd/{}", st.unnamed->fd());
      if (::linkat(AT_FDCWD, from.c_str(), AT_FDCWD, st.tmp.c_str(), AT_SYMLINK_FOLLOW) != 0)
        throw InputError(fmt::format("{}: cannot name the finished file ({})", path, std::strerror(errno)));
      st.named = true;
      if (st.unnamed->close() != 0) throw InputError(fmt::format("{}: write failed ({})", path, std::strerror(st.unnamed->error())));
    }
    std::error_code ec;
    fs::rename(st.tmp, st.target, ec);
    if (ec) throw InputError(fmt::format("{}: cannot rename the finished file into place: {}", path, ec.message()));
    st.named = false;  // in place: nothing to remove
    sync_folder(st.dir);
  } catch (...) {
    st.remove_named();
    throw;
  }
}

// Paths the system refuses (too long, not a folder on the way): the user's input, not our bug.
template <class F>
auto as_input_errors(const std::string& path, F&& f) {
  try {
    return f();
  } catch (const fs::filesystem_error& e) {
    throw InputError(fmt::format("{}: cannot write ({})", path, e.code().message()));
  }
}

}  // namespace

void check_output_path(const std::string& path) {
  try {
    target_folder(resolve_target(path), path);
  } catch (const fs::filesystem_error& e) {
    throw InputError(fmt::format("{}: cannot write ({})", path, e.code().message()));
  }
}

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write) { StagedFile(path, write).commit(); }

StagedFile::StagedFile(const std::string& path, const std::function<void(std::ostream&)>& write)
    : state_(as_input_errors(path, [&] { return stage_file(path, write); })) {}
StagedFile::StagedFile(StagedFile&&) noexcept = default;
StagedFile& StagedFile::operator=(StagedFile&& other) noexcept {
  if (state_) state_->remove_named();
  state_ = std::move(other.state_);
  return *this;
}
StagedFile::~StagedFile() {
  if (state_) state_->remove_named();  // an unnamed file goes with its descriptor
}
void StagedFile::commit() {
  if (!state_) return;
  auto st = std::move(state_);
  as_input_errors(st->path, [&] { commit_file(*st); });
}

}  // namespace adaptiso
