// Raw samples with user-given dimensions, type, byte order, spacing and header size. The file size
// must match exactly: a mismatch almost always means wrong --dims or --type.
#include <fmt/format.h>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"
#include "layout.hpp"

namespace adaptiso {

namespace detail {

RawLayout raw_layout(const std::string& path, const RawOptions& o) {
  const std::uint64_t size = detail::file_size_or_throw(path);
  const std::size_t bytes = checked_volume_bytes(o.dims, scalar_size(o.type), path);
  // Apart: header + data would wrap around for a header near 2^64, and report a wrapped size.
  if (o.header_bytes > size)
    throw OptionError("header_bytes", fmt::format("{} bytes reach past the end of {} ({} bytes)", o.header_bytes, path, size));
  if (size - o.header_bytes != bytes)
    throw InputError(fmt::format("{}: file has {} bytes but {}x{}x{} {} plus a {}-byte header needs {}", path, size, o.dims[0], o.dims[1],
                                 o.dims[2], scalar_name(o.type), o.header_bytes, bytes + o.header_bytes));
  RawLayout l;
  l.header.dims = o.dims;
  l.header.type = o.type;
  l.header.spacing = o.spacing;
  for (int a = 0; a < 3; ++a)
    if (!(l.header.spacing[a] > 0)) throw OptionError("spacing", fmt::format("must be positive (reading {})", path));
  l.offset = o.header_bytes;
  l.swap = o.big_endian == detail::host_is_little_endian();
  return l;
}

}  // namespace detail

Volume read_raw(const std::string& path, const RawOptions& o) {
  detail::RawLayout l = detail::raw_layout(path, o);
  Volume v = std::move(l.header);
  v.bytes = detail::read_bytes(path, l.offset, static_cast<std::uint64_t>(v.voxel_count()) * scalar_size(v.type));
  if (l.swap) detail::byteswap(v.bytes.data(), scalar_size(v.type), static_cast<std::size_t>(v.voxel_count()));
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
