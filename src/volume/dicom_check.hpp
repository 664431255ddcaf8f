// Internal: a structural check of one DICOM file before GDCM reads it (see dicom_check.cpp).
#pragma once
#include <cstdint>
#include <optional>
#include <span>
#include <string>

namespace adaptiso::detail {

struct DicomSummary {
  std::uint32_t rows = 0, columns = 0, bits_allocated = 0, samples = 1;
  std::uint64_t frames = 1, pixel_bytes = 0;
  bool has_pixels = false, encapsulated = false, has_intercept = false;
  std::optional<double> slope;             // RescaleSlope as GDCM reads it
  std::int64_t last_tag = -1;              // the data set's tags must ascend
  std::optional<std::string> photometric;  // PhotometricInterpretation, trailing spaces and NULs dropped
  // Where the data set ends when zero bytes pad the file after the pixel data (0: no padding).
  // GDCM parses padding as empty elements, an exception each: 2.1 s for 2.5 MB of zeros.
  std::uint64_t padded_from = 0;
};

// "DICM" after the 128-byte preamble: the file claims to be DICOM Part 10.
bool has_dicom_magic(const std::string& file);

// Walks every element of the file (sequences and items included) and throws InputError naming the
// file when a length runs past its end, nesting is absurd, or the image the header describes is
// larger than its pixel data can hold. A file without pixel data (DICOMDIR) has has_pixels false.
DicomSummary check_dicom_file(const std::string& file);
// The same for a file's bytes already read.
DicomSummary check_dicom_bytes(std::span<const unsigned char> bytes, const std::string& file);

}  // namespace adaptiso::detail
