// Internal: a DICOM series of one slice per file, opened before its pixel data is read, so that
// slabs of it can be read file by file (VolumeStream; read_dicom_folder reads every slice the same
// way). See read_dicom.cpp.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"

namespace adaptiso::detail {

struct DicomSeries {
  std::string path;                    // the folder or file named
  Volume header;                       // dims, type, spacing, origin, direction, as read_dicom_folder gives them; no samples
  ScalarType stored = ScalarType::u8;  // the files' pixel type (header.type differs when slices are rescaled)
  bool rescale = false;                // some slice's RescaleSlope is not 1 or its RescaleIntercept not 0
  struct File {
    std::string name;
    double slope = 1, inter = 0;  // RescaleSlope and RescaleIntercept as GDCM gives them
  };
  std::vector<File> files;  // in slice order
};

// The series at path with one slice per file (its first file's image read, the others' headers);
// nullopt for a multi-frame file, which is read whole. Throws what read_dicom_folder throws for
// what it reads.
std::optional<DicomSeries> open_dicom_series(const std::string& path);

// Slices z0..z1 of the series into out (header.type samples, x fastest), the same bytes as
// read_dicom_folder's; InputError naming the file when one no longer matches the series.
void read_dicom_slices(const DicomSeries& series, std::int64_t z0, std::int64_t z1, unsigned char* out);

}  // namespace adaptiso::detail
