// A structural walk of a DICOM file before GDCM sees it. GDCM asserts (aborting the process) on
// some truncated or corrupt files and allocates what a corrupt Rows/Columns/NumberOfFrames says;
// this walk refuses, with one line, every element whose length runs past the end of the file,
// nesting deeper than any real file, and images larger than their pixel data can hold.
#include "dicom_check.hpp"

#include <fmt/format.h>
#include <gdcmDicts.h>
#include <gdcmGlobal.h>
#include <gdcmVR.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <span>

#include "adaptiso/error.hpp"
#include "io_util.hpp"

namespace adaptiso::detail {
namespace {

constexpr std::uint32_t kUndefined = 0xffffffffu;
constexpr int kMaxDepth = 16;

struct Reader {
  std::span<const unsigned char> b;
  const std::string& file;
  bool explicit_vr = true;
  bool big_endian = false;

  [[noreturn]] void fail(const std::string& why, std::size_t at) const {
    throw InputError(fmt::format("{}: not a valid DICOM file ({} at byte {})", file, why, at));
  }
  std::uint16_t u16(std::size_t at) const {
    if (at + 2 > b.size()) fail("truncated", at);
    return big_endian ? static_cast<std::uint16_t>(b[at] << 8 | b[at + 1]) : static_cast<std::uint16_t>(b[at] | b[at + 1] << 8);
  }
  std::uint32_t u32(std::size_t at) const {
    if (at + 4 > b.size()) fail("truncated", at);
    std::uint32_t x = 0;
    for (int i = 0; i < 4; ++i) x |= static_cast<std::uint32_t>(b[at + i]) << (big_endian ? 24 - 8 * i : 8 * i);
    return x;
  }
};

struct Element {
  std::uint16_t group = 0, element = 0;
  std::string vr;
  std::uint32_t length = 0;
  std::size_t value = 0;  // offset of the value
};

bool known_vr(const std::string& vr) {
  static const char* names[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FD", "FL", "IS", "LO", "LT", "OB", "OD", "OF", "OL", "OV",
                                "OW", "PN", "SH", "SL", "SQ", "SS", "ST", "SV", "TM", "UC", "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  return std::any_of(std::begin(names), std::end(names), [&](const char* n) { return vr == n; });
}

// The VR GDCM expects of the elements it reads into typed attributes; it asserts on any other.
const char* expected_vr(std::uint16_t group, std::uint16_t element) {
  const std::uint32_t tag = static_cast<std::uint32_t>(group) << 16 | element;
  switch (tag) {
    case 0x00020002:
    case 0x00020003:
    case 0x00020010:
    case 0x00080016:
    case 0x00080018:
    case 0x0020000d:
    case 0x0020000e:
      return "UI";
    case 0x00080060:
    case 0x00280004:
      return "CS";
    case 0x00180050:
    case 0x00180088:
    case 0x00200032:
    case 0x00200037:
    case 0x00280030:
    case 0x00281050:
    case 0x00281051:
    case 0x00281052:
    case 0x00281053:
      return "DS";
    case 0x00200013:
    case 0x00280008:
      return "IS";
    case 0x00280002:
    case 0x00280006:
    case 0x00280010:
    case 0x00280011:
    case 0x00280100:
    case 0x00280101:
    case 0x00280102:
    case 0x00280103:
      return "US";
    default:
      return nullptr;
  }
}

bool long_vr(const std::string& vr) {
  static const char* names[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN", "UR", "UT", "UV"};
  return std::any_of(std::begin(names), std::end(names), [&](const char* n) { return vr == n; });
}

Element read_element(const Reader& r, std::size_t at) {
  Element e;
  e.group = r.u16(at);
  e.element = r.u16(at + 2);
  const bool item_tag = e.group == 0xfffe;  // items and delimiters never carry a VR
  if (r.explicit_vr && !item_tag) {
    if (at + 6 > r.b.size()) r.fail("truncated", at);
    e.vr.assign(reinterpret_cast<const char*>(&r.b[at + 4]), 2);
    // GDCM guesses (and can loop) when an explicit-VR file holds an unknown VR; refuse it first.
    if (!known_vr(e.vr)) r.fail(fmt::format("element ({:04x},{:04x}) has no valid VR", e.group, e.element), at);
    if (const char* vr = expected_vr(e.group, e.element); vr && e.vr != vr)
      r.fail(fmt::format("element ({:04x},{:04x}) has VR {}, not {}", e.group, e.element, e.vr, vr), at);
    // GDCM asserts when an element it reads as a typed attribute has a VR its dictionary does not
    // allow; every public element is held to that dictionary.
    const gdcm::VR dict = gdcm::Global::GetInstance().GetDicts().GetDictEntry(gdcm::Tag(e.group, e.element)).GetVR();
    const gdcm::VR file = gdcm::VR::GetVRType(e.vr.c_str());
    if (dict != gdcm::VR::INVALID && dict != gdcm::VR::UN && file != gdcm::VR::UN && !dict.Compatible(file))
      r.fail(fmt::format("element ({:04x},{:04x}) has VR {}, not {}", e.group, e.element, e.vr, gdcm::VR::GetVRString(dict)), at);
    if (long_vr(e.vr)) {
      e.length = r.u32(at + 8);
      e.value = at + 12;
    } else {
      e.length = r.u16(at + 6);
      e.value = at + 8;
    }
  } else {
    e.length = r.u32(at + 4);
    e.value = at + 8;
  }
  if (e.length != kUndefined && (e.value > r.b.size() || e.length > r.b.size() - e.value))
    r.fail(fmt::format("element ({:04x},{:04x}) of {} bytes runs past the end", e.group, e.element, e.length), at);
  return e;
}

std::size_t walk_dataset(const Reader& r, std::size_t at, std::size_t end, bool until_delimiter, int depth, DicomSummary* top);

// An undefined-length sequence or encapsulated pixel data: items until the sequence delimiter.
std::size_t walk_items(const Reader& r, std::size_t at, int depth) {
  if (depth > kMaxDepth) r.fail("sequences nested too deep", at);
  while (true) {
    Element it = read_element(r, at);
    if (it.group == 0xfffe && it.element == 0xe0dd) return it.value;  // sequence delimiter
    if (it.group != 0xfffe || it.element != 0xe000) r.fail("expected an item in a sequence", at);
    if (it.length == kUndefined)
      at = walk_dataset(r, it.value, r.b.size(), true, depth + 1, nullptr);
    else
      at = it.value + it.length;
  }
}

std::uint32_t us_value(const Reader& r, const Element& e) { return e.length >= 2 ? r.u16(e.value) : 0; }
// A text element's bytes, as the file holds them (its length is defined).
std::string text_value(const Reader& r, const Element& e) { return {reinterpret_cast<const char*>(&r.b[e.value]), e.length}; }

std::size_t walk_dataset(const Reader& r, std::size_t at, std::size_t end, bool until_delimiter, int depth, DicomSummary* top) {
  if (depth > kMaxDepth) r.fail("sequences nested too deep", at);
  while (at < end) {
    Element e = read_element(r, at);
    if (until_delimiter && e.group == 0xfffe && e.element == 0xe00d) return e.value;  // item delimiter
    if (top) {
      const std::uint32_t tag = static_cast<std::uint32_t>(e.group) << 16 | e.element;
      if (tag == 0x00280010) top->rows = us_value(r, e);
      if (tag == 0x00280011) top->columns = us_value(r, e);
      if (tag == 0x00280100) top->bits_allocated = us_value(r, e);
      if (tag == 0x00280002) top->samples = us_value(r, e);
      if (tag == 0x00280008 && e.length != kUndefined) {
        const std::string s = text_value(r, e);
        auto n = parse_finite(trim(s.substr(0, s.find('\\'))));
        top->frames = n && *n >= 1 && *n <= 1e9 ? static_cast<std::uint64_t>(*n) : 1;
      }
      // DICOM orders a data set's tags (PS3.5 §7.1). GDCM does not check it: its header read stops
      // at the first tag past the one it wants, its full read keeps the first of two equal tags,
      // so a file out of order reads differently in each and fuzz_dicom found it asserting on the
      // rescale and the pixel format those disagreements give.
      if (std::int64_t{tag} <= top->last_tag)
        r.fail(fmt::format("tags out of order: ({:04x},{:04x}) after ({:04x},{:04x})", e.group, e.element, top->last_tag >> 16,
                           top->last_tag & 0xffff),
               at);
      top->last_tag = tag;
      if ((tag == 0x00281052 || tag == 0x00281053) && e.length != kUndefined) {
        // GDCM asserts on a zero rescale slope, and takes a missing one as zero when an intercept
        // is given; it reads the value as a stream does (a leading number, else 0).
        const std::string v = text_value(r, e);
        const double x = std::strtod(trim(v.substr(0, v.find('\\'))).c_str(), nullptr);
        if (tag == 0x00281052) top->has_intercept = true;
        if (tag == 0x00281053) top->slope = x;
      }
      if (tag == 0x00280004 && e.length != kUndefined) {
        std::string v = text_value(r, e);
        while (!v.empty() && (v.back() == ' ' || v.back() == '\0')) v.pop_back();
        top->photometric = v;
      }
      if (tag == 0x7fe00010) {
        top->has_pixels = true;
        top->encapsulated = e.length == kUndefined;
        top->pixel_bytes = e.length == kUndefined ? r.b.size() - e.value : e.length;
      }
    }
    at = e.length == kUndefined ? walk_items(r, e.value, depth + 1) : e.value + e.length;
    // Zero bytes after the pixel data are padding some writers add, which GDCM skips, except 4 to
    // 7 of them: a whole tag but no whole VR and length, on which it asserts (measured for 0 to
    // 40 bytes: only those abort). Anything else there GDCM parses, so it is walked like the rest.
    if (top && top->has_pixels &&
        std::all_of(r.b.begin() + static_cast<long>(std::min(at, r.b.size())), r.b.end(), [](unsigned char c) { return c == 0; })) {
      const std::size_t padding = r.b.size() - std::min(at, r.b.size());
      if (padding >= 4 && padding < 8) r.fail(fmt::format("{} zero bytes after the pixel data (a tag without its length)", padding), at);
      if (padding > 0) top->padded_from = at;
      return r.b.size();
    }
  }
  if (until_delimiter) r.fail("item without its delimiter", at);
  return at;
}

}  // namespace

bool has_dicom_magic(const std::string& file) {
  const std::uint64_t size = file_size_or_throw(file);
  if (size < 132) return false;
  const auto head = read_bytes(file, 128, 4);
  return std::memcmp(head.data(), "DICM", 4) == 0;
}

DicomSummary check_dicom_file(const std::string& file) { return check_dicom_bytes(read_bytes(file, 0, file_size_or_throw(file)), file); }

DicomSummary check_dicom_bytes(std::span<const unsigned char> bytes, const std::string& file) {
  Reader r{bytes, file};
  std::size_t at = 0;
  std::string syntax = "1.2.840.10008.1.2";  // implicit VR little endian: files without a meta group
  if (bytes.size() >= 132 && std::memcmp(&bytes[128], "DICM", 4) == 0) {
    at = 132;
    while (at < bytes.size() && r.u16(at) == 0x0002) {
      Element e = read_element(r, at);
      if (e.length == kUndefined) r.fail("undefined length in the file meta information", at);
      // GDCM asserts on a sequence there ("Should not happen"; fuzz_dicom found it in CI).
      if (e.vr == "SQ") r.fail(fmt::format("a sequence (VR SQ) in the file meta information, element (0002,{:04x})", e.element), at);
      if (e.element == 0x0010) syntax = trim(text_value(r, e).c_str());
      at = e.value + e.length;
    }
  }
  DicomSummary s;
  if (syntax == "1.2.840.10008.1.2.1.99") return s;  // deflated: the data set cannot be walked unpacked; GDCM inflates it
  r.explicit_vr = syntax != "1.2.840.10008.1.2";
  r.big_endian = syntax == "1.2.840.10008.1.2.2";
  walk_dataset(r, at, bytes.size(), false, 0, &s);
  if (!s.has_pixels) return s;  // a DICOMDIR or report: not an image, the caller skips it
  if ((s.has_intercept || s.slope) && !(s.slope && *s.slope != 0 && std::isfinite(*s.slope)))
    throw InputError(fmt::format("{}: DICOM RescaleIntercept without a usable RescaleSlope (it must be a non-zero number)", file));
  // GDCM asserts on other sample counts; adaptiso reads grey-scale images of whole bytes.
  if (s.samples != 1) throw InputError(fmt::format("{}: {} samples per pixel; adaptiso reads grey-scale images", file, s.samples));
  // GDCM asserts on a palette image without its lookup tables, and takes a damaged value for the
  // nearest one it knows (fuzz_dicom: "PALET\0\1ME2"); grey-scale is MONOCHROME1 or 2.
  if (s.photometric && *s.photometric != "MONOCHROME1" && *s.photometric != "MONOCHROME2") {
    std::string printable = s.photometric->substr(0, 32);  // one line, whatever the file holds
    for (char& c : printable)
      if (c < 0x20 || c > 0x7e) c = '?';
    throw InputError(fmt::format("{}: PhotometricInterpretation '{}' is not grey-scale (MONOCHROME1 or MONOCHROME2)", file, printable));
  }
  if (s.bits_allocated != 8 && s.bits_allocated != 16 && s.bits_allocated != 32 && s.bits_allocated != 64)
    throw InputError(fmt::format("{}: BitsAllocated {} is not supported (8, 16, 32 or 64)", file, s.bits_allocated));
  const std::uint64_t image =
      std::uint64_t{s.rows} * s.columns * s.frames * std::max<std::uint32_t>(s.samples, 1) * ((s.bits_allocated + 7) / 8);
  if (image == 0)
    throw InputError(
        fmt::format("{}: DICOM image is empty (Rows {}, Columns {}, BitsAllocated {})", file, s.rows, s.columns, s.bits_allocated));
  // Compressed pixel data: no codec GDCM supports gets near 1000:1 on real images.
  const std::uint64_t can_hold = s.encapsulated ? s.pixel_bytes * 1000 : s.pixel_bytes;
  if (image > can_hold)
    throw InputError(fmt::format("{}: DICOM header says {}x{}x{} at {} bits ({} bytes) but the pixel data holds {} bytes", file, s.columns,
                                 s.rows, s.frames, s.bits_allocated, image, s.pixel_bytes));
  return s;
}

}  // namespace adaptiso::detail
