// Atomic outputs: the bytes written are the bytes on disk, whatever the sizes of the pieces and of
// the file around the writer's block (4096) and buffer (16 MiB) sizes, straight to the disk or
// through the page cache (ADAPTISO_NO_DIRECT_IO, or a tmpfs such as /dev/shm that refuses O_DIRECT).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/error.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Writes `bytes` in pieces of varying sizes (single characters among them, through overflow),
// flushing now and then (the writer then gives its buffers back and keeps a partial block aside).
void write_in_pieces(std::ostream& out, const std::string& bytes, std::mt19937& rng) {
  for (std::size_t at = 0; at < bytes.size();) {
    if (rng() % 5 == 0) out.flush();
    const std::size_t piece = rng() % 3 == 0 ? 1 : std::min<std::size_t>(bytes.size() - at, 1 + rng() % (std::size_t{5} << 20));
    if (piece == 1)
      out.put(bytes[at]);
    else
      out.write(bytes.data() + at, static_cast<std::streamsize>(piece));
    at += piece;
  }
}

}  // namespace

TEST(AtomicFile, BytesOnDiskAreTheBytesWrittenAtEverySizeAroundBlocksAndBuffers) {
  constexpr std::size_t MiB = std::size_t{1} << 20;
  std::mt19937 rng(3);
  std::string pool(2 * 16 * MiB + 3 * 4096 + 7, '\0');
  for (auto& c : pool) c = static_cast<char>(rng());
  testutil::TempDir dir("atomic");
  std::vector<std::string> folders{dir.path.string()};
  if (std::filesystem::is_directory("/dev/shm")) folders.push_back("/dev/shm");
  for (const bool direct : {true, false})
    for (const auto& folder : folders)
      for (std::size_t size : {std::size_t{0}, std::size_t{1}, std::size_t{4095}, std::size_t{4096}, std::size_t{4097}, 16 * MiB - 1,
                               16 * MiB, 16 * MiB + 1, 16 * MiB + 4096 + 5, pool.size()}) {
        const std::string path = folder + "/adaptiso-atomic-" + std::to_string(size) + ".bin";
        const std::string bytes = pool.substr(0, size);
        if (!direct) setenv("ADAPTISO_NO_DIRECT_IO", "1", 1);
        write_file_atomically(path, [&](std::ostream& out) { write_in_pieces(out, bytes, rng); });
        EXPECT_EQ(std::filesystem::file_size(path), size) << path;
        EXPECT_TRUE(read_all(path) == bytes) << path;
        std::filesystem::remove(path);
        unsetenv("ADAPTISO_NO_DIRECT_IO");
      }
}

TEST(AtomicFile, AFailingWriteLeavesTheOldFileAndNoTemporary) {
  testutil::TempDir dir("atomic-fail");
  const std::string path = dir / "kept.bin";
  write_file_atomically(path, [](std::ostream& out) { out << "old"; });
  EXPECT_THROW(write_file_atomically(path,
                                     [](std::ostream& out) {
                                       out << std::string(20 << 20, 'x');  // past the first buffer: a write in flight
                                       throw InputError("stopped");
                                     }),
               InputError);
  EXPECT_EQ(read_all(path), "old");
  for (const auto& e : std::filesystem::directory_iterator(dir.path)) EXPECT_EQ(e.path().filename().string(), "kept.bin");
}

// A staged file is nowhere under its name (nor under any, as an unnamed file) until commit(), and
// one never committed leaves nothing behind; with or without unnamed files (ADAPTISO_NO_TMPFILE).
TEST(AtomicFile, AStagedFileAppearsOnlyWhenCommitted) {
  for (const bool named : {false, true}) {
    SCOPED_TRACE(named ? "named temporary" : "unnamed temporary");
    if (named) setenv("ADAPTISO_NO_TMPFILE", "1", 1);
    testutil::TempDir dir("atomic-staged");
    const std::string kept = dir / "kept.bin", dropped = dir / "dropped.bin";
    write_file_atomically(kept, [](std::ostream& out) { out << "old"; });
    {
      StagedFile a(kept, [](std::ostream& out) { out << std::string(20 << 20, 'n'); });
      StagedFile b(dropped, [](std::ostream& out) { out << "never"; });
      EXPECT_EQ(read_all(kept), "old");
      EXPECT_FALSE(std::filesystem::exists(dropped));
      StagedFile moved = std::move(a);
      moved.commit();
      moved.commit();  // once only
      EXPECT_EQ(read_all(kept), std::string(20 << 20, 'n'));
    }  // b goes uncommitted
    EXPECT_FALSE(std::filesystem::exists(dropped));
    for (const auto& e : std::filesystem::directory_iterator(dir.path)) EXPECT_EQ(e.path().filename().string(), "kept.bin");
    if (named) unsetenv("ADAPTISO_NO_TMPFILE");
  }
}
