// adaptiso/atomic_file.hpp — every output is written to a temporary file beside the target and
// renamed over it only when complete, so a failure never leaves a half-written file. Where the file
// system allows it the temporary file has no name until it is complete (O_TMPFILE, then linkat), so
// nothing of it is visible while it is written and nothing is left when the process is killed,
// even by SIGKILL; elsewhere it is ".NAME.tmp<pid>-<hex>", and such files whose process is gone are
// removed when NAME is next written.
#pragma once
#include <cstddef>
#include <functional>
#include <memory>
#include <ostream>
#include <string>

namespace adaptiso {

// What a file being written holds in memory: two buffers of 16 MiB, one filled while the other
// goes to the disk (given back by a flush of the stream).
constexpr std::size_t kAtomicFileBufferBytes = std::size_t{32} << 20;

// Calls write(stream) on a temporary file in the target's folder, flushes and fsyncs it, then
// renames it to `path`. A symbolic link is written through (its target is replaced, the link
// stays; a dangling link's target is created, in its folder, which must exist); an existing file
// keeps its permission bits; anything at `path` that is not a regular file
// (a folder, device, FIFO) is refused with InputError rather than replaced. On any exception (or a
// stream error) the temporary file is removed and InputError (for an unwritable path) or the
// original exception propagates; SIGINT, SIGTERM and SIGHUP remove it too when they would
// otherwise kill the process (their handlers are left alone when the host installed its own).
void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write);

// A file written in full as write_file_atomically writes it, put in place only by commit(): for
// outputs that must appear together or not at all (`mpirun … adaptiso extract`: no mesh under its
// final name unless every rank's are written). Until then nothing is visible under the target's
// name or, where the file system allows it, under any (an unnamed file, freed with the process
// even on SIGKILL); the destructor of one never committed removes it. A staged file holds a
// descriptor open until commit. Throws as write_file_atomically, commit() InputError when the
// rename fails (the file is then removed).
class StagedFile {
public:
  StagedFile(const std::string& path, const std::function<void(std::ostream&)>& write);
  StagedFile(StagedFile&&) noexcept;
  StagedFile& operator=(StagedFile&&) noexcept;
  ~StagedFile();
  void commit();  // once; later calls do nothing
  struct State;

private:
  std::unique_ptr<State> state_;
};

// Throws InputError now for what write_file_atomically(path, ...) would refuse before writing (a
// missing folder, something at path that is not a regular file), so that long work is not done
// for an output that cannot be written.
void check_output_path(const std::string& path);

}  // namespace adaptiso
