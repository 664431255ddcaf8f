#include "io_util.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"

#include <bzlib.h>
#include <fmt/format.h>
#include <libdeflate.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>

namespace adaptiso::detail {

std::uint64_t file_size_or_throw(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const auto st = fs::status(path, ec);
  if (ec && ec != std::errc::no_such_file_or_directory) throw InputError(fmt::format("{}: cannot read ({})", path, ec.message()));
  if (!fs::exists(st)) throw InputError(fmt::format("{}: no such file", path));
  if (fs::is_directory(st)) throw InputError(fmt::format("{}: is a folder, expected a file", path));
  // A FIFO, socket or device has no size and may block or never end: only regular files are read.
  if (!fs::is_regular_file(st)) throw InputError(fmt::format("{}: is not a regular file (a FIFO, socket or device)", path));
  auto s = fs::file_size(path, ec);
  if (ec) throw InputError(fmt::format("{}: cannot read ({})", path, ec.message()));
  return s;
}

void check_holds(const std::string& path, std::uint64_t offset, std::uint64_t count) {
  const std::uint64_t size = file_size_or_throw(path);
  if (offset > size || count > size - offset)
    throw InputError(fmt::format("{}: file is truncated: needs {} bytes from offset {}, has {}", path, count, offset,
                                 size > offset ? size - offset : 0));
}

void check_fits(const std::string& path, std::uint64_t bytes) {
  if (bytes < kBigArrayBytes) return;  // headers and small volumes: no need to ask the system
  check_memory(bytes, path + ": reading it", "", "a volume is read whole (free memory, or raise --memory-limit)");
}

std::vector<unsigned char> read_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count) {
  check_holds(path, offset, count);
  check_fits(path, count);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(fmt::format("{}: cannot open ({})", path, std::strerror(errno)));
  std::vector<unsigned char> buf;
  resize_big(buf, count);
  in.seekg(static_cast<std::streamoff>(offset));
  in.read(reinterpret_cast<char*>(buf.data()), static_cast<std::streamsize>(count));
  if (static_cast<std::uint64_t>(in.gcount()) != count) throw InputError(fmt::format("{}: read failed", path));
  return buf;
}

std::string read_text(const std::string& path, std::uint64_t max_bytes) {
  std::uint64_t size = file_size_or_throw(path);
  if (size > max_bytes) throw InputError(fmt::format("{}: too large for a header ({} bytes)", path, size));
  auto b = read_bytes(path, 0, size);
  return std::string(b.begin(), b.end());
}

namespace {

// libdeflate decodes a whole stream in one call at twice zlib's speed (the bunny's 79 MB of gzip:
// 0.23 s against 0.48 s), but says no more than "bad data" of a broken one. So a stream is
// decoded by it first, and only one it refuses goes through zlib, whose diagnosis (cut short,
// too long, corrupt) the user gets. Trailing output to discard needs zlib's streaming.
bool inflate_whole(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected) {
  if (n < 2) return false;
  struct Free {
    void operator()(libdeflate_decompressor* d) const { libdeflate_free_decompressor(d); }
  };
  const std::unique_ptr<libdeflate_decompressor, Free> d(libdeflate_alloc_decompressor());
  if (!d) return false;
  std::size_t in = 0, out = 0;
  // The same headers as zlib's automatic detection (windowBits 15 + 32): gzip, or zlib.
  const bool gzip = src[0] == 0x1f && src[1] == 0x8b;
  const libdeflate_result r = gzip ? libdeflate_gzip_decompress_ex(d.get(), src, n, dst, expected, &in, &out)
                                   : libdeflate_zlib_decompress_ex(d.get(), src, n, dst, expected, &in, &out);
  return r == LIBDEFLATE_SUCCESS && out == expected;
}

}  // namespace

void inflate_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what,
                   bool allow_trailing) {
  if (!allow_trailing && inflate_whole(src, n, dst, expected)) return;
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) throw std::runtime_error("zlib: inflateInit failed");
  std::size_t in_done = 0, out_done = 0;
  int rc = Z_OK;
  // zlib counts in uInt; feed and drain in chunks so >4 GiB volumes work.
  constexpr std::size_t chunk = std::size_t{1} << 30;
  while (true) {
    if (zs.avail_in == 0 && in_done < n) {
      zs.next_in = const_cast<Bytef*>(src + in_done);
      zs.avail_in = static_cast<uInt>(std::min(chunk, n - in_done));
      in_done += zs.avail_in;
    }
    unsigned char extra[4096];
    bool full = out_done >= expected;
    zs.next_out = full ? extra : dst + out_done;
    zs.avail_out = full ? (allow_trailing ? sizeof extra : 1) : static_cast<uInt>(std::min(chunk, expected - out_done));
    uInt before = zs.avail_out;
    rc = inflate(&zs, Z_NO_FLUSH);
    std::size_t produced = before - zs.avail_out;
    if (full && allow_trailing) produced = 0;
    if (full && produced > 0) {
      inflateEnd(&zs);
      throw InputError(fmt::format("{}: compressed data holds more than the expected {} bytes", what, expected));
    }
    out_done += produced;
    if (rc == Z_STREAM_END) break;
    if (rc == Z_BUF_ERROR && zs.avail_in == 0 && in_done >= n) {
      inflateEnd(&zs);
      if (out_done >= expected) throw InputError(fmt::format("{}: compressed stream ends without its trailer (cut short)", what));
      throw InputError(fmt::format("{}: compressed stream is cut short ({} of {} bytes decoded)", what, out_done, expected));
    }
    if (rc != Z_OK && rc != Z_BUF_ERROR) {
      std::string msg = zs.msg ? zs.msg : "corrupt data";
      inflateEnd(&zs);
      throw InputError(fmt::format("{}: compressed data is corrupt ({})", what, msg));
    }
  }
  inflateEnd(&zs);
  if (out_done != expected) throw InputError(fmt::format("{}: compressed data holds {} bytes, expected {}", what, out_done, expected));
}

// The whole-number value of a header field; InputError when it is not one or out of range.
std::int64_t whole_number(double x, double lo, double hi, const std::string& what) {
  if (!(x >= lo && x <= hi) || x != std::floor(x))
    throw InputError(fmt::format("{}: {} is not a whole number in [{}, {}]", what, x, lo, hi));
  return static_cast<std::int64_t>(x);
}

std::vector<std::string> numbered_files(const std::string& edf, std::int64_t slices, const std::string& what) {
  auto sp = edf.find(' ');
  if (sp == std::string::npos) throw InputError(fmt::format("{} pattern needs 'min max step'", what));
  const std::string pattern = edf.substr(0, sp);
  auto nums = parse_number_list(edf.substr(sp + 1), -1, what);
  if (nums.size() < 2 || nums.size() > 3) throw InputError(fmt::format("{} pattern needs 'min max step'", what));
  const std::int64_t lo = whole_number(nums[0], -1e9, 1e9, what), hi = whole_number(nums[1], -1e9, 1e9, what);
  const std::int64_t step = nums.size() > 2 ? whole_number(nums[2], 1, 1e9, what) : 1;
  if (hi < lo) throw InputError(fmt::format("{}: range {} … {} is empty", what, lo, hi));
  const std::int64_t count = (hi - lo) / step + 1;
  if (count > slices) throw InputError(fmt::format("{}: range names {} files for {} slices", what, count, slices));

  const auto pct = pattern.find('%');
  std::size_t end = pct + 1;
  const bool zero = end < pattern.size() && pattern[end] == '0';
  if (zero) ++end;
  std::size_t width = 0;
  while (end < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[end])) && width < 100)
    width = width * 10 + static_cast<std::size_t>(pattern[end++] - '0');
  if (end >= pattern.size() || pattern[end] != 'd' || width > 12 || pattern.find('%', end) != std::string::npos)
    throw InputError(fmt::format("{}: pattern '{}' must hold exactly one %d (or %0Nd, N ≤ 12)", what, pattern.substr(0, 80)));
  const std::string before = pattern.substr(0, pct), after = pattern.substr(end + 1);

  std::vector<std::string> names;
  for (std::int64_t i = lo; i <= hi; i += step) {
    std::string digits = std::to_string(i < 0 ? -i : i);
    const std::size_t sign = i < 0 ? 1 : 0;
    if (digits.size() + sign < width) digits.insert(0, width - digits.size() - sign, zero ? '0' : ' ');
    if (sign) digits.insert(zero ? 0 : digits.find_first_not_of(' '), 1, '-');
    names.push_back(before + digits + after);
  }
  return names;
}

std::vector<unsigned char> inflate_prefix(const unsigned char* src, std::size_t n, std::size_t max_out) {
  std::vector<unsigned char> out(max_out);
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) throw std::runtime_error("zlib: inflateInit failed");
  zs.next_in = const_cast<Bytef*>(src);
  zs.avail_in = static_cast<uInt>(std::min<std::size_t>(n, std::numeric_limits<uInt>::max()));
  zs.next_out = out.data();
  zs.avail_out = static_cast<uInt>(max_out);
  while (zs.avail_out > 0) {
    const int rc = inflate(&zs, Z_NO_FLUSH);
    if (rc != Z_OK) break;  // the end, corrupt data or no more input: what was decoded is the prefix
  }
  out.resize(max_out - zs.avail_out);
  inflateEnd(&zs);
  return out;
}

void bunzip2_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what) {
  bz_stream bz{};
  if (BZ2_bzDecompressInit(&bz, 0, 0) != BZ_OK) throw std::runtime_error("bzip2: init failed");
  std::size_t in_done = 0, out_done = 0;
  constexpr std::size_t chunk = std::size_t{1} << 30;  // bzip2 counts in unsigned int
  auto fail = [&](const std::string& why) {
    BZ2_bzDecompressEnd(&bz);
    throw InputError(fmt::format("{}: {}", what, why));
  };
  while (true) {
    if (bz.avail_in == 0 && in_done < n) {
      bz.next_in = reinterpret_cast<char*>(const_cast<unsigned char*>(src + in_done));
      bz.avail_in = static_cast<unsigned>(std::min(chunk, n - in_done));
      in_done += bz.avail_in;
    }
    char extra;
    const bool full = out_done >= expected;
    bz.next_out = full ? &extra : reinterpret_cast<char*>(dst + out_done);
    bz.avail_out = full ? 1 : static_cast<unsigned>(std::min(chunk, expected - out_done));
    const unsigned before = bz.avail_out, in_before = bz.avail_in;
    const int rc = BZ2_bzDecompress(&bz);
    const std::size_t produced = before - bz.avail_out;
    if (full && produced > 0) fail(fmt::format("compressed data holds more than the expected {} bytes", expected));
    out_done += produced;
    if (rc == BZ_STREAM_END) break;
    if (rc != BZ_OK) fail(fmt::format("bzip2 data is corrupt (code {})", rc));
    if (bz.avail_in == 0 && in_done >= n && produced == 0 && in_before == 0)
      fail(fmt::format("compressed stream is cut short ({} of {} bytes decoded)", out_done, expected));
  }
  BZ2_bzDecompressEnd(&bz);
  if (out_done != expected) throw InputError(fmt::format("{}: compressed data holds {} bytes, expected {}", what, out_done, expected));
}

std::vector<double> parse_values(std::string_view text, std::size_t count, const std::string& what) {
  auto values = parse_number_list(text, -1, what);
  if (values.size() != count) throw InputError(fmt::format("{}: text data holds {} values, expected {}", what, values.size(), count));
  for (std::size_t i = 0; i < values.size(); ++i)
    if (!std::isfinite(values[i])) throw InputError(fmt::format("{}: value {} is not finite", what, i));
  return values;
}

bool host_is_little_endian() { return std::endian::native == std::endian::little; }

void byteswap(unsigned char* data, std::size_t es, std::size_t count) {
  if (es == 1) return;
  for (std::size_t i = 0; i < count; ++i) std::reverse(data + i * es, data + (i + 1) * es);
}

std::string trim(std::string_view s) {
  auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string_view::npos) return {};
  auto e = s.find_last_not_of(" \t\r\n");
  return std::string(s.substr(b, e - b + 1));
}

std::string lower(std::string_view s) {
  std::string r(s);
  for (auto& c : r) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return r;
}

}  // namespace adaptiso::detail
