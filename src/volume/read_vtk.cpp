// VTK readers: XML ImageData (.vti: ascii, inline base64 "binary", appended raw or base64, zlib
// compressed or not) and legacy STRUCTURED_POINTS (.vtk: ASCII or big-endian BINARY). Both are
// parsed directly; only the scalar point-data array is read.
#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

namespace adaptiso {
namespace {

std::optional<ScalarType> vtk_xml_type(const std::string& t) {
  static const std::map<std::string, ScalarType> m = {
      {"Int8", ScalarType::i8},     {"UInt8", ScalarType::u8},    {"Int16", ScalarType::i16},
      {"UInt16", ScalarType::u16},  {"Int32", ScalarType::i32},   {"UInt32", ScalarType::u32},
      {"Float32", ScalarType::f32}, {"Float64", ScalarType::f64}, {"Char", ScalarType::i8}};
  auto it = m.find(t);
  if (it == m.end()) return std::nullopt;
  return it->second;
}

std::optional<ScalarType> vtk_legacy_type(const std::string& t) {
  static const std::map<std::string, ScalarType> m = {
      {"unsigned_char", ScalarType::u8}, {"char", ScalarType::i8}, {"unsigned_short", ScalarType::u16}, {"short", ScalarType::i16},
      {"unsigned_int", ScalarType::u32}, {"int", ScalarType::i32}, {"float", ScalarType::f32},          {"double", ScalarType::f64}};
  auto it = m.find(t);
  if (it == m.end()) return std::nullopt;
  return it->second;
}

// Decodes base64 four characters at a time, so concatenated padded segments (VTK encodes the
// compression header and the blocks separately) decode to the concatenation of their bytes.
std::vector<unsigned char> base64_decode(std::string_view s, const std::string& what, std::size_t max_bytes) {
  auto val = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+') return 62;
    if (c == '/') return 63;
    if (c == '=') return -2;
    return -1;
  };
  std::vector<unsigned char> out;
  out.reserve(std::min(max_bytes, s.size() / 4 * 3));
  int q[4], n = 0;
  for (char c : s) {
    int x = val(c);
    if (x == -1) {
      if (std::isspace(static_cast<unsigned char>(c))) continue;
      throw InputError(fmt::format("{}: invalid base64 character '{}'", what, c));
    }
    q[n++] = x;
    if (n == 4) {
      n = 0;
      if (q[0] < 0 || q[1] < 0) throw InputError(fmt::format("{}: invalid base64 padding", what));
      out.push_back(static_cast<unsigned char>((q[0] << 2) | (q[1] >> 4)));
      if (q[2] >= 0) out.push_back(static_cast<unsigned char>(((q[1] & 15) << 4) | (q[2] >> 2)));
      if (q[2] >= 0 && q[3] >= 0) out.push_back(static_cast<unsigned char>(((q[2] & 3) << 6) | q[3]));
      if (out.size() >= max_bytes) break;
    }
  }
  return out;
}

// Attributes of the first tag named `tag` at or after `from` in an XML text.
struct Tag {
  std::map<std::string, std::string> attrs;
  std::size_t begin = std::string::npos, end = std::string::npos;  // '<' and one past '>'
};

Tag find_tag(const std::string& xml, const std::string& tag, std::size_t from, std::size_t until) {
  Tag t;
  std::size_t p = from;
  while (true) {
    p = xml.find("<" + tag, p);
    if (p == std::string::npos || p >= until) return t;
    char c = xml[p + 1 + tag.size()];
    if (std::isspace(static_cast<unsigned char>(c)) || c == '>' || c == '/') break;
    p += 1;
  }
  auto close = xml.find('>', p);
  if (close == std::string::npos) return t;
  t.begin = p;
  t.end = close + 1;
  std::string body = xml.substr(p + 1 + tag.size(), close - p - 1 - tag.size());
  std::size_t i = 0;
  while (i < body.size()) {
    auto eq = body.find('=', i);
    if (eq == std::string::npos) break;
    std::string name = detail::trim(body.substr(i, eq - i));
    auto q1 = body.find_first_of("\"'", eq);
    if (q1 == std::string::npos) break;
    auto q2 = body.find(body[q1], q1 + 1);
    if (q2 == std::string::npos) break;
    t.attrs[name] = body.substr(q1 + 1, q2 - q1 - 1);
    i = q2 + 1;
  }
  return t;
}

// The compression header (block count, block size, last block's size) must describe exactly
// `bytes`, computed without wrapping: sizes from the file are hostile until checked.
void check_block_layout(std::uint64_t nb, std::uint64_t bs, std::uint64_t last, std::uint64_t max_blocks, std::uint64_t bytes,
                        const std::string& path) {
  auto corrupt = [&](const char* why) { throw InputError(fmt::format("{}: compression header is corrupt ({})", path, why)); };
  if (nb > max_blocks) corrupt("more blocks than the data can hold");
  if (nb == 0) {
    if (bytes != 0) corrupt("no blocks");
    return;
  }
  if (bs == 0) corrupt("block size 0");
  if (last > bs) corrupt("last block larger than the block size");
  std::uint64_t total = 0;
  if (__builtin_mul_overflow(nb - 1, bs, &total) || __builtin_add_overflow(total, last ? last : bs, &total)) corrupt("sizes overflow");
  if (total != bytes) throw InputError(fmt::format("{}: compressed array holds {} bytes, expected {}", path, total, bytes));
}

}  // namespace

Volume read_vti(const std::string& path) {
  const std::uint64_t fsize = detail::file_size_or_throw(path);
  auto all = detail::read_bytes(path, 0, fsize);
  std::string text(all.begin(), all.end());
  std::size_t appended_tag = text.find("<AppendedData");
  std::size_t xml_end = appended_tag == std::string::npos ? text.size() : appended_tag;
  Tag file = find_tag(text, "VTKFile", 0, xml_end);
  if (file.begin == std::string::npos) throw InputError(fmt::format("{}: not a VTK XML file (no <VTKFile>)", path));
  if (file.attrs["type"] != "ImageData") throw InputError(fmt::format("{}: VTK XML type '{}' is not ImageData", path, file.attrs["type"]));
  const bool big = file.attrs["byte_order"] == "BigEndian";
  const std::size_t hs = file.attrs["header_type"] == "UInt64" ? 8 : 4;
  const std::string compressor = file.attrs["compressor"];
  if (!compressor.empty() && compressor != "vtkZLibDataCompressor")
    throw InputError(fmt::format("{}: compressor {} is not supported (only zlib)", path, compressor));
  Tag img = find_tag(text, "ImageData", file.end, xml_end);
  if (img.begin == std::string::npos) throw InputError(fmt::format("{}: no <ImageData> element", path));
  auto ext = parse_number_list(img.attrs["WholeExtent"], 6, path + ": WholeExtent");
  Dims dims{};
  for (int a = 0; a < 3; ++a) {
    double n = ext[2 * a + 1] - ext[2 * a] + 1;
    if (!(n >= 1) || n > 1e12) throw InputError(fmt::format("{}: WholeExtent is empty or inverted", path));
    dims[a] = static_cast<std::int64_t>(n);
  }
  Volume v;
  if (!img.attrs["Spacing"].empty()) {
    auto s = parse_number_list(img.attrs["Spacing"], 3, path + ": Spacing");
    for (int a = 0; a < 3; ++a) v.spacing[a] = std::abs(s[a]);
  }
  if (!img.attrs["Direction"].empty()) {
    auto d = parse_number_list(img.attrs["Direction"], 9, path + ": Direction");
    std::copy(d.begin(), d.end(), v.direction.begin());
  }
  Vec3 o{0, 0, 0};
  if (!img.attrs["Origin"].empty()) {
    auto od = parse_number_list(img.attrs["Origin"], 3, path + ": Origin");
    o = {od[0], od[1], od[2]};
  }
  v.origin = o;
  v.origin = v.grid_to_world({ext[0] * v.spacing[0], ext[2] * v.spacing[1], ext[4] * v.spacing[2]});

  Tag piece = find_tag(text, "Piece", img.end, xml_end);
  if (piece.begin == std::string::npos) throw InputError(fmt::format("{}: no <Piece> element", path));
  if (find_tag(text, "Piece", piece.end, xml_end).begin != std::string::npos)
    throw InputError(fmt::format("{}: several pieces; adaptiso reads single-piece .vti files", path));
  Tag pd = find_tag(text, "PointData", piece.end, xml_end);
  if (pd.begin == std::string::npos) throw InputError(fmt::format("{}: no <PointData>", path));
  std::size_t pd_close = text.find("</PointData>", pd.end);
  if (pd_close == std::string::npos) pd_close = pd.end;
  std::string want = pd.attrs["Scalars"];
  Tag arr;
  for (std::size_t p = pd.end;;) {
    Tag t = find_tag(text, "DataArray", p, pd_close);
    if (t.begin == std::string::npos) break;
    std::string nc = t.attrs.count("NumberOfComponents") ? t.attrs["NumberOfComponents"] : "1";
    if ((want.empty() && nc == "1") || (!want.empty() && t.attrs["Name"] == want)) {
      arr = t;
      if (nc != "1") throw InputError(fmt::format("{}: array '{}' has {} components; adaptiso reads scalars", path, t.attrs["Name"], nc));
      break;
    }
    p = t.end;
  }
  if (arr.begin == std::string::npos) throw InputError(fmt::format("{}: no scalar point-data array", path));
  auto type = vtk_xml_type(arr.attrs["type"]);
  if (!type) throw InputError(fmt::format("{}: DataArray type '{}' is not supported", path, arr.attrs["type"]));
  v.dims = dims;
  v.type = *type;
  const std::size_t es = scalar_size(*type);
  const std::size_t bytes = checked_volume_bytes(dims, es, path);
  detail::check_fits(path, bytes);
  const std::string format = arr.attrs["format"];
  std::size_t arr_close = text.find("</DataArray>", arr.end);

  auto read_uint = [&](const unsigned char* p) -> std::uint64_t {
    unsigned char b[8];
    std::memcpy(b, p, hs);
    if (big != !detail::host_is_little_endian()) std::reverse(b, b + hs);
    if (hs == 4) {
      std::uint32_t x;
      std::memcpy(&x, b, 4);
      return x;
    }
    std::uint64_t x;
    std::memcpy(&x, b, 8);
    return x;
  };
  // Decodes one binary array (header + data, compressed or not) starting at `p` with `n` bytes.
  auto decode_binary = [&](const unsigned char* p, std::size_t n) {
    if (n < hs) throw InputError(fmt::format("{}: data array is truncated", path));
    if (compressor.empty()) {
      std::uint64_t len = read_uint(p);
      if (len != bytes) throw InputError(fmt::format("{}: data array holds {} bytes, expected {}", path, len, bytes));
      if (n - hs < bytes) throw InputError(fmt::format("{}: data array is truncated ({} of {} bytes)", path, n - hs, bytes));
      v.bytes.assign(p + hs, p + hs + bytes);
      return;
    }
    if (n < 3 * hs) throw InputError(fmt::format("{}: compression header is truncated", path));
    std::uint64_t nb = read_uint(p), bs = read_uint(p + hs), last = read_uint(p + 2 * hs);
    check_block_layout(nb, bs, last, n / hs, bytes, path);
    std::size_t off = (3 + nb) * hs;
    if (off > n) throw InputError(fmt::format("{}: compression header is truncated", path));
    v.bytes.resize(bytes);
    std::size_t out = 0;
    for (std::uint64_t b = 0; b < nb; ++b) {
      std::uint64_t cs = read_uint(p + (3 + b) * hs);
      std::uint64_t want_out = (b + 1 == nb && last) ? last : bs;
      if (cs > n - off) throw InputError(fmt::format("{}: compressed block {} is truncated", path, b));
      if (want_out > bytes - out) throw InputError(fmt::format("{}: compressed block {} runs past the array", path, b));
      detail::inflate_exact(p + off, cs, v.bytes.data() + out, want_out, path);
      off += cs;
      out += want_out;
    }
  };

  if (format == "ascii") {
    if (arr_close == std::string::npos) throw InputError(fmt::format("{}: unterminated DataArray", path));
    auto nums =
        detail::parse_values(std::string_view(text).substr(arr.end, arr_close - arr.end), static_cast<std::size_t>(v.voxel_count()), path);
    v.bytes.assign(bytes, 0);
    for (std::size_t i = 0; i < nums.size(); ++i) v.set(static_cast<std::int64_t>(i), nums[i]);
  } else if (format == "binary") {
    if (arr_close == std::string::npos) throw InputError(fmt::format("{}: unterminated DataArray", path));
    auto raw = base64_decode(std::string_view(text).substr(arr.end, arr_close - arr.end), path, SIZE_MAX);
    decode_binary(raw.data(), raw.size());
  } else if (format == "appended") {
    if (appended_tag == std::string::npos) throw InputError(fmt::format("{}: array is appended but there is no <AppendedData>", path));
    Tag ap = find_tag(text, "AppendedData", appended_tag, text.size());
    std::size_t us = text.find('_', ap.end);
    if (us == std::string::npos) throw InputError(fmt::format("{}: <AppendedData> has no '_' marker", path));
    // Compared as a number before it becomes a count: an offset of 1e40 bytes has no integer.
    const double off = parse_number_list(arr.attrs["offset"], 1, path + ": offset")[0];
    if (!(off >= 0) || off != std::floor(off))
      throw InputError(fmt::format("{}: appended data offset {} is not a whole number of bytes", path, off));
    if (off > static_cast<double>(text.size() - (us + 1)))
      throw InputError(fmt::format("{}: appended data offset {} is beyond the end of the file", path, off));
    const std::size_t start = us + 1 + static_cast<std::size_t>(off);
    if (ap.attrs["encoding"] == "base64") {
      std::size_t stop = text.find('<', start);
      auto raw =
          base64_decode(std::string_view(text).substr(start, stop == std::string::npos ? std::string::npos : stop - start), path, SIZE_MAX);
      decode_binary(raw.data(), raw.size());
    } else {
      decode_binary(all.data() + start, all.size() - start);
    }
  } else {
    throw InputError(fmt::format("{}: DataArray format '{}' is not supported", path, format));
  }
  if (format != "ascii" && big != !detail::host_is_little_endian())
    detail::byteswap(v.bytes.data(), es, static_cast<std::size_t>(v.voxel_count()));
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0)) throw InputError(fmt::format("{}: spacing along axis {} is not positive", path, a));
  check_finite(v, path);
  return v;
}

Volume read_legacy_vtk(const std::string& path) {
  const std::uint64_t fsize = detail::file_size_or_throw(path);
  auto head = detail::read_bytes(path, 0, std::min<std::uint64_t>(fsize, 1 << 16));
  std::size_t pos = 0;
  auto next_line = [&]() -> std::optional<std::string> {
    if (pos >= head.size()) return std::nullopt;
    std::size_t e = pos;
    while (e < head.size() && head[e] != '\n') ++e;
    std::string l(head.begin() + static_cast<long>(pos), head.begin() + static_cast<long>(e));
    pos = std::min(e + 1, head.size());  // the last line may lack its newline
    return detail::trim(l);
  };
  auto l0 = next_line();
  if (!l0 || l0->rfind("# vtk DataFile", 0) != 0) throw InputError(fmt::format("{}: not a legacy VTK file", path));
  next_line();  // title
  std::optional<std::string> mode;
  while ((mode = next_line()) && mode->empty()) {
  }
  if (!mode || (*mode != "BINARY" && *mode != "ASCII")) throw InputError(fmt::format("{}: expected ASCII or BINARY", path));
  const bool binary = *mode == "BINARY";
  Volume v;
  Dims dims{0, 0, 0};
  std::optional<ScalarType> type;
  bool have_scalars = false;
  while (auto l = next_line()) {
    if (l->empty()) continue;
    auto sp = l->find(' ');
    std::string key = detail::lower(l->substr(0, sp)), rest = sp == std::string::npos ? "" : l->substr(sp + 1);
    if (key == "dataset") {
      if (detail::trim(rest) != "STRUCTURED_POINTS")
        throw InputError(fmt::format("{}: DATASET {} is not supported (STRUCTURED_POINTS only)", path, detail::trim(rest)));
    } else if (key == "dimensions") {
      auto d = parse_number_list(rest, 3, path + ": DIMENSIONS");
      for (int a = 0; a < 3; ++a) {
        if (!(d[a] >= 1) || d[a] > 1e12) throw InputError(fmt::format("{}: DIMENSIONS must be positive", path));
        dims[a] = static_cast<std::int64_t>(d[a]);
      }
    } else if (key == "spacing" || key == "aspect_ratio") {
      auto s = parse_number_list(rest, 3, path + ": SPACING");
      for (int a = 0; a < 3; ++a) v.spacing[a] = std::abs(s[a]);
    } else if (key == "origin") {
      auto o = parse_number_list(rest, 3, path + ": ORIGIN");
      v.origin = {o[0], o[1], o[2]};
    } else if (key == "point_data") {
      continue;
    } else if (key == "scalars") {
      std::string r = detail::trim(rest);
      auto s1 = r.find(' ');
      if (s1 == std::string::npos) throw InputError(fmt::format("{}: SCALARS line lacks a type", path));
      std::string t = detail::trim(r.substr(s1 + 1));
      auto s2 = t.find(' ');
      std::string comps = s2 == std::string::npos ? "1" : detail::trim(t.substr(s2 + 1));
      t = t.substr(0, s2);
      type = vtk_legacy_type(t);
      if (!type) throw InputError(fmt::format("{}: scalar type '{}' is not supported", path, t));
      if (comps != "1") throw InputError(fmt::format("{}: {} components per point; adaptiso reads scalars", path, comps));
      have_scalars = true;
    } else if (key == "lookup_table") {
      if (!have_scalars) throw InputError(fmt::format("{}: LOOKUP_TABLE before SCALARS", path));
      break;
    } else if (key == "cell_data" || key == "field" || key == "color_scalars" || key == "vectors") {
      throw InputError(fmt::format("{}: {} before the point scalars is not supported", path, key));
    }
  }
  if (!have_scalars) throw InputError(fmt::format("{}: no SCALARS point data", path));
  v.dims = dims;
  v.type = *type;
  const std::size_t es = scalar_size(*type);
  const std::size_t bytes = checked_volume_bytes(dims, es, path);
  detail::check_fits(path, bytes);
  if (binary) {
    auto data = detail::read_bytes(path, pos, bytes);
    v.bytes = std::move(data);
    if (detail::host_is_little_endian()) detail::byteswap(v.bytes.data(), es, static_cast<std::size_t>(v.voxel_count()));
  } else {
    if (bytes > fsize * es) throw InputError(fmt::format("{}: file too short for {} values", path, v.voxel_count()));
    std::string t = detail::read_text(path, fsize);
    // Other attributes may follow the scalars: read the first voxel_count values.
    auto nums = parse_number_list(std::string_view(t).substr(pos), -1, path);
    if (nums.size() < static_cast<std::size_t>(v.voxel_count()))
      throw InputError(fmt::format("{}: file is truncated: {} of {} values", path, nums.size(), v.voxel_count()));
    nums.resize(static_cast<std::size_t>(v.voxel_count()));
    for (std::size_t i = 0; i < nums.size(); ++i)
      if (!std::isfinite(nums[i])) throw InputError(fmt::format("{}: value {} is not finite", path, i));
    v.bytes.assign(bytes, 0);
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, nums[static_cast<std::size_t>(i)]);
  }
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0)) throw InputError(fmt::format("{}: spacing along axis {} is not positive", path, a));
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
