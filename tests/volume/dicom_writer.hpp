// Writes minimal DICOM Part 10 files (explicit VR little endian) of one 8×8 uint16 slice, byte by
// byte: the hostile-file tests and the series tests build on them.
#pragma once
#include <cstdint>
#include <optional>
#include <string>

#include "test_util.hpp"

namespace testutil {

struct DicomSlice {
  std::string intercept, slope;                 // RescaleIntercept and RescaleSlope; empty: left out
  std::optional<double> z;                      // ImagePositionPatient (0, 0, z), an axial orientation and a pixel spacing; none: left out
  std::string pixels = std::string(128, '\1');  // the 64 samples' bytes (per frame)
  int frames = 0;                               // NumberOfFrames; 0: left out
};

inline std::string dicom_file(const DicomSlice& s) {
  auto el = [](std::uint16_t g, std::uint16_t e, const char* vr, std::string v) {
    if (v.size() % 2) v += '\0';
    std::string out(reinterpret_cast<const char*>(&g), 2);
    out.append(reinterpret_cast<const char*>(&e), 2);
    out += vr;
    if (std::string(vr) == "OW" || std::string(vr) == "OB") {
      out += std::string(2, '\0') + u32(static_cast<std::uint32_t>(v.size()));
    } else {
      const auto n = static_cast<std::uint16_t>(v.size());
      out.append(reinterpret_cast<const char*>(&n), 2);
    }
    return out + v;
  };
  auto us = [](std::uint16_t x) { return std::string(reinterpret_cast<const char*>(&x), 2); };
  const std::string meta_body = el(2, 1, "OB", std::string("\0\1", 2)) + el(2, 2, "UI", "1.2.840.10008.5.1.4.1.1.4") +
                                el(2, 3, "UI", "1.2.3.4") + el(2, 0x10, "UI", "1.2.840.10008.1.2.1");
  std::string ds = el(0x20, 0xE, "UI", "1.2.3.5");
  if (s.z) ds += el(0x20, 0x32, "DS", "0\\0\\" + std::to_string(*s.z)) + el(0x20, 0x37, "DS", "1\\0\\0\\0\\1\\0");
  ds += el(0x28, 2, "US", us(1)) + el(0x28, 4, "CS", "MONOCHROME2");
  if (s.frames > 0) ds += el(0x28, 8, "IS", std::to_string(s.frames));
  ds += el(0x28, 0x10, "US", us(8)) + el(0x28, 0x11, "US", us(8));
  if (s.z) ds += el(0x28, 0x30, "DS", "0.5\\0.75");
  ds += el(0x28, 0x100, "US", us(16)) + el(0x28, 0x101, "US", us(12)) + el(0x28, 0x102, "US", us(11)) + el(0x28, 0x103, "US", us(0));
  if (!s.intercept.empty()) ds += el(0x28, 0x1052, "DS", s.intercept);
  if (!s.slope.empty()) ds += el(0x28, 0x1053, "DS", s.slope);
  ds += el(0x7fe0, 0x10, "OW", s.pixels);
  return std::string(128, '\0') + "DICM" + el(2, 0, "UL", u32(static_cast<std::uint32_t>(meta_body.size()))) + meta_body + ds;
}

}  // namespace testutil
