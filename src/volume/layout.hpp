// Where a file's samples are and how they are stored: everything read_nrrd, read_raw, read_nifti
// and read_metaimage check before they read the data, shared with the region reader
// (volume_regions.cpp).
#pragma once
#include <teem/nrrd.h>

#include <cstdint>
#include <optional>
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

// MetaImage: what read_metaimage checks before the data, and where each data file's bytes are.
struct MetaImageLayout {
  Volume header;                      // dims, type and geometry; no samples
  std::vector<std::string> files;     // data files, in order (the header's own path for LOCAL)
  std::vector<std::uint64_t> starts;  // the first byte of each file's data
  std::vector<std::uint64_t> stored;  // bytes of each file's data (compressed: the zlib stream's)
  std::uint64_t bytes = 0;            // the decoded samples' size
  bool compressed = false;
  bool swap = false;
};
MetaImageLayout metaimage_layout(const std::string& path);

// NIfTI's scl_slope and scl_inter: a stored sample s becomes s × slope + inter, of `type` (float32,
// or float64 for 32-bit integer and float64 samples).
struct NiftiScaling {
  double slope = 1, inter = 0;
  ScalarType type = ScalarType::f32;
};
// NIfTI-1/-2: what read_nifti checks before the data (through nifticlib's header reader).
struct NiftiLayout {
  Volume header;             // dims, the stored type, geometry; no samples
  std::string file;          // the .nii, or the .img beside a .hdr
  std::uint64_t offset = 0;  // of the first sample (in the inflated stream when gz)
  std::uint64_t bytes = 0;
  bool gz = false;
  bool swap = false;
  std::optional<NiftiScaling> scaling;
};
NiftiLayout nifti_layout(const std::string& path);
// Applies the scaling to stored samples (read_nifti's rule, voxel by voxel), then refuses NaN and
// infinities naming `where`.
void apply_scaling(Volume& v, const NiftiScaling& s, const std::string& where);

}  // namespace adaptiso::detail
