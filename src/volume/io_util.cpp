#include "io_util.hpp"

#include <fmt/format.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace adaptiso::detail {

std::uint64_t file_size_or_throw(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw InputError(fmt::format("{}: no such file", path));
  if (std::filesystem::is_directory(path, ec)) throw InputError(fmt::format("{}: is a folder, expected a file", path));
  auto s = std::filesystem::file_size(path, ec);
  if (ec) throw InputError(fmt::format("{}: cannot read ({})", path, ec.message()));
  return s;
}

std::vector<unsigned char> read_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count) {
  std::uint64_t size = file_size_or_throw(path);
  if (offset > size || count > size - offset)
    throw InputError(fmt::format("{}: file is truncated: needs {} bytes from offset {}, has {}", path, count, offset,
                                 size > offset ? size - offset : 0));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(fmt::format("{}: cannot open ({})", path, std::strerror(errno)));
  std::vector<unsigned char> buf(count);
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

void inflate_exact(const unsigned char* src, std::size_t n, unsigned char* dst, std::size_t expected, const std::string& what) {
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
    unsigned char extra;
    bool full = out_done >= expected;
    zs.next_out = full ? &extra : dst + out_done;
    zs.avail_out = full ? 1 : static_cast<uInt>(std::min(chunk, expected - out_done));
    uInt before = zs.avail_out;
    rc = inflate(&zs, Z_NO_FLUSH);
    std::size_t produced = before - zs.avail_out;
    if (full && produced > 0) {
      inflateEnd(&zs);
      throw InputError(fmt::format("{}: compressed data holds more than the expected {} bytes", what, expected));
    }
    out_done += produced;
    if (rc == Z_STREAM_END) break;
    if (rc == Z_BUF_ERROR && zs.avail_in == 0 && in_done >= n) {
      inflateEnd(&zs);
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
