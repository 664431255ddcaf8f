// adaptiso/volume_io.hpp — reading volumes from the formats our users have, writing NRRD.
//
// read_volume() picks the reader from the path: .nrrd/.nhdr (teem), .nii/.nii.gz (nifticlib,
// NIfTI-1 and -2), .mha/.mhd (MetaImage), .vti (VTK XML ImageData), .vtk (legacy
// STRUCTURED_POINTS), a folder (DICOM series, GDCM), or raw bytes when RawOptions are given.
// Every reader throws InputError with one line naming the file and what is wrong; none allocates
// more than the file could hold (sizes are checked against the bytes on disk — for compressed
// data against the largest expansion the codec allows — before any allocation).
// Values with scale/intercept (NIfTI scl_*, DICOM rescale) become float32 (float64 when the
// native type is 32-bit integer). NaN/Inf values are refused (see check_finite).
// Oblique orientations are kept as stored: the grid is not resampled; Volume::direction records it.
#pragma once
#include <cstdint>
#include <optional>
#include <string>

#include "adaptiso/volume.hpp"

namespace adaptiso {

struct RawOptions {
  Dims dims{0, 0, 0};
  ScalarType type = ScalarType::u8;
  bool big_endian = false;
  Vec3 spacing{1, 1, 1};
  std::uint64_t header_bytes = 0;
};

struct ReadOptions {
  std::optional<RawOptions> raw;  // set: read `path` as raw samples
};

Volume read_volume(const std::string& path, const ReadOptions& options = {});

Volume read_nrrd(const std::string& path);
Volume read_nifti(const std::string& path);
Volume read_metaimage(const std::string& path);
Volume read_dicom_folder(const std::string& path);
Volume read_vti(const std::string& path);
Volume read_legacy_vtk(const std::string& path);
Volume read_raw(const std::string& path, const RawOptions& options);

// Writes an attached-header NRRD (raw encoding, or gzip when `gzip`), atomically.
void write_nrrd(const Volume& v, const std::string& path, bool gzip = false);

}  // namespace adaptiso
