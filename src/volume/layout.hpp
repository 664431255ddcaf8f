// Where a file's samples are and how they are stored: everything read_nrrd and read_raw check
// before they read the data, shared with the region reader (volume_regions.cpp).
#pragma once
#include <teem/nrrd.h>

#include <cstdint>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"
#include "adaptiso/volume_io.hpp"

namespace adaptiso::detail {

struct NrrdLayout {
  Volume header;                   // dims, type and geometry; no samples
  std::vector<std::string> files;  // data files, in order (the header's own path when attached)
  bool attached = false;
  std::uint64_t data_offset = 0;  // attached: the first byte after the header's blank line
  std::uint64_t bytes = 0;        // the decoded samples' size
  const NrrdEncoding* encoding = nullptr;
  bool raw = false;  // raw encoding
  long byte_skip = 0;
  unsigned line_skip = 0;
  bool swap = false;  // samples in the other byte order than this machine's
};

// Throws InputError (one line naming the file) for everything read_nrrd refuses before the data.
NrrdLayout nrrd_layout(const std::string& path);

// Where raw-encoded data of `want` bytes start among the `available` bytes after the header (and
// any line skip), for a byte skip (−1: the data are the last bytes). Throws InputError naming
// `file` when they do not fit.
std::uint64_t raw_data_start(std::uint64_t available, std::uint64_t want, long skip, const std::string& file);

// Raw samples: the volume (no samples) and the first sample's offset. Throws read_raw's errors
// (OptionError for a header past the end or a spacing that is not positive, InputError for a file
// of another size than the options say).
struct RawLayout {
  Volume header;
  std::uint64_t offset = 0;
  bool swap = false;
};
RawLayout raw_layout(const std::string& path, const RawOptions& options);

}  // namespace adaptiso::detail
