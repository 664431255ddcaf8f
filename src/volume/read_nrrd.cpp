// NRRD reader (.nrrd attached, .nhdr detached; raw, gzip, bzip2, ascii, hex; one file per slice).
// teem parses the header's fields, but only after adaptiso has checked every line (teem aborts on
// long lines and loops on hostile file patterns) and with the data-file lines taken out: adaptiso
// resolves the data files and decodes the data itself, every size checked before allocating.
#include <teem/nrrd.h>

#include <algorithm>
#include <optional>

#include <fmt/format.h>
#include <cmath>
#include <filesystem>
#include <mutex>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"
#include "layout.hpp"
#include "util/big_array.hpp"

namespace adaptiso {
namespace {

std::mutex teem_mutex;  // biff's error accumulation is global state

std::string biff_message() {
  char* err = biffGetDone(NRRD);
  std::string all = err ? err : "unknown error";
  free(err);
  // biff stacks one line per call level, outermost first; the innermost says what is wrong.
  std::string best;
  std::size_t pos = 0;
  while (pos < all.size()) {
    auto e = all.find('\n', pos);
    std::string line = detail::trim(all.substr(pos, e == std::string::npos ? std::string::npos : e - pos));
    if (!line.empty()) best = line;
    if (e == std::string::npos) break;
    pos = e + 1;
  }
  // Strip "[nrrd] _nrrdFunction: " prefixes.
  if (auto b = best.find("] "); best.starts_with("[") && b != std::string::npos) best = best.substr(b + 2);
  if (auto c = best.find(": "); c != std::string::npos && best.substr(0, c).find(' ') == std::string::npos) best = best.substr(c + 2);
  return best;
}

struct NrrdHolder {
  Nrrd* n = nrrdNew();
  NrrdIoState* nio = nrrdIoStateNew();
  ~NrrdHolder() {
    nrrdNuke(n);
    nrrdIoStateNix(nio);
  }
};

std::optional<ScalarType> from_teem(int t) {
  switch (t) {
    case nrrdTypeChar:
      return ScalarType::i8;
    case nrrdTypeUChar:
      return ScalarType::u8;
    case nrrdTypeShort:
      return ScalarType::i16;
    case nrrdTypeUShort:
      return ScalarType::u16;
    case nrrdTypeInt:
      return ScalarType::i32;
    case nrrdTypeUInt:
      return ScalarType::u32;
    case nrrdTypeFloat:
      return ScalarType::f32;
    case nrrdTypeDouble:
      return ScalarType::f64;
    default:
      return std::nullopt;
  }
}

constexpr std::size_t kMaxHeaderBytes = 1 << 20;
// teem formats header lines and the file's path into fixed buffers (about 1,000 characters) on its
// error paths and aborts past them; it only ever sees lines below this and never the path.
constexpr std::size_t kMaxLineChars = 512;

// The header as teem will see it, and what adaptiso takes from it itself: where the data is.
struct NrrdHeader {
  std::string text;                // validated lines without "data file", for nrrdStringRead
  std::vector<std::string> files;  // data files, resolved; empty: attached after the header
  std::uint64_t data_offset = 0;   // attached data: first byte after the blank line
};

std::vector<std::string> header_lines(const std::vector<unsigned char>& head, bool whole_file, std::uint64_t& data_offset,
                                      const std::string& path) {
  std::vector<std::string> lines;
  std::size_t pos = 0, number = 0;
  while (true) {
    if (pos >= head.size()) {
      if (!whole_file) throw InputError(fmt::format("{}: NRRD header has no blank line within its first MiB", path));
      data_offset = head.size();
      return lines;
    }
    std::size_t e = pos;
    while (e < head.size() && head[e] != '\n') ++e;
    std::string line(head.begin() + static_cast<long>(pos), head.begin() + static_cast<long>(e));
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = e + 1;
    if (line.empty()) {
      data_offset = std::min(pos, head.size());
      return lines;
    }
    ++number;
    for (char c : line)
      if (static_cast<unsigned char>(c) < 0x20 && c != '\t')
        throw InputError(fmt::format("{}: NRRD header line {} holds a control character (binary data in the header?)", path, number));
    // Comments and key:=value pairs (Slicer writes long ones) mean nothing to adaptiso: teem never
    // sees them, so they need no length limit.
    const auto colon = line.find(':');
    if (line.starts_with("#") || (colon != std::string::npos && colon + 1 < line.size() && line[colon + 1] == '=')) continue;
    if (line.size() > kMaxLineChars)
      throw InputError(fmt::format("{}: NRRD header line {} is longer than {} characters", path, number, kMaxLineChars));
    lines.push_back(std::move(line));
  }
}

// "data file: NAME", "data file: LIST [subdim]" (names on the following lines) or
// "data file: FORMAT MIN MAX STEP [subdim]"; names resolved against the header's folder.
std::vector<std::string> data_files(const std::string& value, const std::vector<std::string>& list, std::int64_t slices,
                                    const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(path).parent_path();
  auto resolve = [&](const std::string& name) {
    fs::path p(name);
    return (p.is_absolute() ? p : dir / p).string();
  };
  std::vector<std::string> files;
  if (value == "LIST" || value.starts_with("LIST ")) {
    for (const auto& l : list) files.push_back(resolve(detail::trim(l)));
    if (files.empty()) throw InputError(fmt::format("{}: data file LIST names no files", path));
  } else if (value.find('%') != std::string::npos) {
    // FORMAT MIN MAX STEP [SUBDIM]: the sub-dimension only says how much each file holds, which
    // is checked as "the files divide the volume evenly".
    std::vector<std::string> tok;
    for (std::size_t i = 0; i < value.size();) {
      auto j = value.find_first_of(" \t", i);
      if (j == std::string::npos) j = value.size();
      if (j > i) tok.push_back(value.substr(i, j - i));
      i = j + 1;
    }
    if (tok.size() != 4 && tok.size() != 5) throw InputError(fmt::format("{}: data file pattern needs 'FORMAT MIN MAX STEP'", path));
    if (tok[3].starts_with("-")) throw InputError(fmt::format("{}: data file pattern with a negative step is not supported", path));
    for (const auto& f : detail::numbered_files(tok[0] + " " + tok[1] + " " + tok[2] + " " + tok[3], slices, path + ": data file"))
      files.push_back(resolve(f));
  } else {
    files.push_back(resolve(value));
  }
  return files;
}

NrrdHeader read_header(const std::string& path, std::uint64_t size) {
  auto head = detail::read_bytes(path, 0, std::min<std::uint64_t>(size, kMaxHeaderBytes));
  if (head.size() < 8 || std::string(head.begin(), head.begin() + 7) != "NRRD000")
    throw InputError(fmt::format("{}: not a NRRD file (no NRRD000x magic)", path));
  NrrdHeader h;
  auto lines = header_lines(head, size <= kMaxHeaderBytes, h.data_offset, path);
  std::optional<std::string> data_file;
  std::vector<std::string> list;
  std::int64_t slices = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const std::string& l = lines[i];
    const auto colon = l.find(':');
    const std::string key = colon == std::string::npos ? "" : detail::lower(detail::trim(l.substr(0, colon)));
    if (key == "data file" || key == "datafile") {
      data_file = detail::trim(l.substr(colon + 1));
      if (*data_file == "LIST" || data_file->starts_with("LIST ")) {
        list.assign(lines.begin() + static_cast<long>(i) + 1, lines.end());  // LIST ends the header
        break;
      }
      continue;
    }
    if (key == "sizes") {
      // The last axis counts the slices a per-slice file pattern may name.
      auto sizes = parse_number_list(l.substr(colon + 1), -1, path + ": sizes");
      if (!sizes.empty()) slices = detail::whole_number(sizes.back(), 1, 1e12, path + ": sizes");
    }
    h.text += l;
    h.text += '\n';
  }
  h.text += '\n';
  if (data_file) h.files = data_files(*data_file, list, slices, path);
  return h;
}

// The encoded bytes of one data file after its "line skip" lines (and, for raw data, "byte skip").
std::vector<unsigned char> encoded_bytes(const std::string& file, std::uint64_t start, unsigned line_skip, const std::string& path) {
  const std::uint64_t size = detail::file_size_or_throw(file);
  if (start > size) throw InputError(fmt::format("{}: data starts past the end of {}", path, file));
  auto bytes = detail::read_bytes(file, start, size - start);
  std::size_t pos = 0;
  for (unsigned l = 0; l < line_skip; ++l) {
    while (pos < bytes.size() && bytes[pos] != '\n') ++pos;
    if (pos >= bytes.size()) throw InputError(fmt::format("{}: {} has fewer than {} lines to skip", path, file, line_skip));
    ++pos;
  }
  bytes.erase(bytes.begin(), bytes.begin() + static_cast<long>(pos));
  return bytes;
}

// Decodes one file's share of the volume (`out` bytes) in the header's encoding.
void decode_file(const NrrdEncoding* e, long skip, std::vector<unsigned char> enc, unsigned char* out, std::size_t count, ScalarType type,
                 const std::string& file) {
  const std::size_t es = scalar_size(type);
  const std::size_t want = count * es;
  if (e == nrrdEncodingRaw) {
    const std::size_t from = detail::raw_data_start(enc.size(), want, skip, file);
    std::copy_n(enc.begin() + static_cast<long>(from), want, out);
    return;
  }
  if (skip < 0) throw InputError(fmt::format("{}: byte skip -1 is only defined for raw encoding", file));
  const std::size_t skip_bytes = static_cast<std::size_t>(skip);
  if (e == nrrdEncodingGzip || e == nrrdEncodingBzip2) {
    std::vector<unsigned char> plain(skip_bytes + want);
    if (e == nrrdEncodingGzip)
      detail::inflate_exact(enc.data(), enc.size(), plain.data(), plain.size(), file);
    else
      detail::bunzip2_exact(enc.data(), enc.size(), plain.data(), plain.size(), file);
    std::copy_n(plain.begin() + static_cast<long>(skip_bytes), want, out);
    return;
  }
  if (skip_bytes > enc.size()) throw InputError(fmt::format("{}: byte skip {} is past the end of the data", file, skip));
  std::string_view text(reinterpret_cast<const char*>(enc.data()) + skip_bytes, enc.size() - skip_bytes);
  if (e == nrrdEncodingHex) {
    std::size_t n = 0;
    int hi = -1;
    for (char c : text) {
      if (std::isspace(static_cast<unsigned char>(c))) continue;
      if (!std::isxdigit(static_cast<unsigned char>(c))) throw InputError(fmt::format("{}: '{}' is not a hex digit", file, c));
      int d = std::isdigit(static_cast<unsigned char>(c)) ? c - '0' : std::tolower(static_cast<unsigned char>(c)) - 'a' + 10;
      if (hi < 0) {
        hi = d;
        continue;
      }
      if (n == want) throw InputError(fmt::format("{}: hex data holds more than the {} bytes the header says", file, want));
      out[n++] = static_cast<unsigned char>(hi * 16 + d);
      hi = -1;
    }
    if (n != want || hi >= 0) throw InputError(fmt::format("{}: hex data holds {} bytes, expected {}", file, n, want));
    return;
  }
  if (e == nrrdEncodingAscii) {
    auto values = detail::parse_values(text, count, file);
    Volume slab = make_volume({static_cast<std::int64_t>(count), 1, 1}, type);
    for (std::size_t i = 0; i < count; ++i) slab.set(static_cast<std::int64_t>(i), values[i]);
    std::copy_n(slab.bytes.begin(), want, out);
    return;
  }
  throw InputError(fmt::format("{}: NRRD encoding '{}' is not supported", file, e->name));
}

// An upper bound of the decoded bytes a file can give, checked before anything is allocated.
std::uint64_t decodable_bytes(const NrrdEncoding* e, std::uint64_t on_disk, std::size_t es) {
  if (e == nrrdEncodingGzip) return detail::max_inflated_size(on_disk);
  if (e == nrrdEncodingBzip2) return on_disk * 50000;
  if (e == nrrdEncodingAscii) return (on_disk / 2 + 1) * es;  // a digit and a separator per value
  if (e == nrrdEncodingHex) return on_disk / 2;
  return on_disk;
}

}  // namespace

namespace detail {

std::uint64_t raw_data_start(std::uint64_t available, std::uint64_t want, long skip, const std::string& file) {
  // byte skip -1: the data are the file's last bytes.
  const std::uint64_t from = skip < 0 ? (available >= want ? available - want : available + 1) : static_cast<std::uint64_t>(skip);
  if (from > available || available - from < want)
    throw InputError(
        fmt::format("{}: file is truncated: holds {} data bytes, needs {}", file, available - std::min(from, available), want));
  return from;
}

NrrdLayout nrrd_layout(const std::string& path) {
  const std::uint64_t size = detail::file_size_or_throw(path);
  NrrdHeader header = read_header(path, size);
  std::lock_guard lock(teem_mutex);
  nrrdStateVerboseIO = 0;
  NrrdHolder h;
  h.nio->skipData = AIR_TRUE;  // adaptiso reads the data itself, with every size checked
  if (nrrdStringRead(h.n, header.text.c_str(), h.nio))
    throw InputError(fmt::format("{}: cannot read NRRD header: {}", path, biff_message()));
  auto t = from_teem(h.n->type);
  if (!t)
    throw InputError(fmt::format("{}: NRRD type '{}' is not supported (use 8/16/32-bit integers, float or double)", path,
                                 airEnumStr(nrrdType, h.n->type)));
  NrrdLayout out;
  Volume& v = out.header;
  v.type = *t;
  unsigned first = 0;
  if (h.n->dim == 4 && h.n->axis[0].size == 1)
    first = 1;  // a 1-component axis in front
  else if (h.n->dim != 2 && h.n->dim != 3)
    throw InputError(fmt::format("{}: NRRD has {} axes; adaptiso reads 2D slices and 3D scalar volumes", path, h.n->dim));
  v.dims = {1, 1, 1};
  for (unsigned a = first; a < h.n->dim; ++a) v.dims[a - first] = static_cast<std::int64_t>(h.n->axis[a].size);
  const std::size_t es = scalar_size(v.type);
  out.bytes = checked_volume_bytes(v.dims, es, path);

  out.attached = header.files.empty();
  out.files = out.attached ? std::vector<std::string>{path} : header.files;
  out.data_offset = out.attached ? header.data_offset : 0;
  if (out.bytes % (out.files.size() * es) != 0)
    throw InputError(fmt::format("{}: {} data files do not divide the volume evenly", path, out.files.size()));
  std::uint64_t bound = 0, on_disk = 0;
  for (const auto& f : out.files) {
    std::uint64_t s = detail::file_size_or_throw(f);
    if (out.attached) s -= std::min(s, header.data_offset);
    on_disk += s;
    bound += decodable_bytes(h.nio->encoding, s, es);
  }
  if (out.bytes > bound)
    throw InputError(fmt::format("{}: header says {}x{}x{} {} ({} bytes) but the data file(s) hold only {} bytes{}", path, v.dims[0],
                                 v.dims[1], v.dims[2], scalar_name(v.type), out.bytes, on_disk,
                                 h.nio->encoding->isCompression ? " compressed" : ""));
  out.encoding = h.nio->encoding;
  out.byte_skip = h.nio->byteSkip;
  out.line_skip = h.nio->lineSkip;
  const bool text = h.nio->encoding == nrrdEncodingAscii;
  if (!text && es > 1 && h.nio->endian == airEndianUnknown)
    throw InputError(fmt::format("{}: NRRD header lacks 'endian' for {}-byte values", path, es));
  out.swap = !text && es > 1 && (h.nio->endian == airEndianBig) == detail::host_is_little_endian();
  out.raw = h.nio->encoding == nrrdEncodingRaw;

  // Geometry: "space directions" (world vectors) when present, else per-axis "spacings".
  const unsigned nax = h.n->dim - first;
  for (unsigned a = 0; a < nax; ++a) {
    const NrrdAxisInfo& ax = h.n->axis[first + a];
    double len = 0;
    bool have_dir = h.n->spaceDim >= 3;
    for (unsigned c = 0; have_dir && c < 3; ++c) {
      if (!std::isfinite(ax.spaceDirection[c]))
        have_dir = false;
      else
        len += ax.spaceDirection[c] * ax.spaceDirection[c];
    }
    len = std::sqrt(len);
    if (have_dir && len > 0) {
      v.spacing[a] = len;
      for (unsigned c = 0; c < 3; ++c) v.direction[3 * c + a] = ax.spaceDirection[c] / len;
    } else if (std::isfinite(ax.spacing) && ax.spacing != 0) {
      v.spacing[a] = std::abs(ax.spacing);
      if (ax.spacing < 0) v.direction[3 * a + a] = -1;
    }
  }
  if (h.n->spaceDim >= 3)
    for (unsigned c = 0; c < 3; ++c)
      if (std::isfinite(h.n->spaceOrigin[c])) v.origin[c] = h.n->spaceOrigin[c];
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0) || !std::isfinite(v.spacing[a]))
      throw InputError(fmt::format("{}: spacing along axis {} is not a positive number", path, a));
  return out;
}

}  // namespace detail

Volume read_nrrd(const std::string& path) {
  detail::NrrdLayout layout = detail::nrrd_layout(path);
  Volume v = std::move(layout.header);
  {
    std::vector<unsigned char> bytes;
    detail::check_fits(path, layout.bytes);
    detail::resize_big(bytes, layout.bytes);
    v.bytes = std::move(bytes);
  }
  const std::size_t es = scalar_size(v.type), per_file = layout.bytes / layout.files.size();
  for (std::size_t i = 0; i < layout.files.size(); ++i)
    decode_file(layout.encoding, layout.byte_skip, encoded_bytes(layout.files[i], layout.data_offset, layout.line_skip, path),
                v.bytes.data() + i * per_file, per_file / es, v.type, layout.files[i]);
  if (layout.swap) detail::byteswap(v.bytes.data(), es, layout.bytes / es);
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
