// Raw samples with user-given dimensions, type, byte order, spacing and header size. The file size
// must match exactly: a mismatch almost always means wrong --dims or --type.
#include <fmt/format.h>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

namespace adaptiso {

Volume read_raw(const std::string& path, const RawOptions& o) {
  const std::uint64_t size = detail::file_size_or_throw(path);
  const std::size_t bytes = checked_volume_bytes(o.dims, scalar_size(o.type), path);
  // Apart: header + data would wrap around for a header near 2^64, and report a wrapped size.
  if (o.header_bytes > size)
    throw OptionError("header_bytes", fmt::format("{} bytes reach past the end of {} ({} bytes)", o.header_bytes, path, size));
  if (size - o.header_bytes != bytes)
    throw InputError(fmt::format("{}: file has {} bytes but {}x{}x{} {} plus a {}-byte header needs {}", path, size, o.dims[0], o.dims[1],
                                 o.dims[2], scalar_name(o.type), o.header_bytes, bytes + o.header_bytes));
  Volume v;
  v.dims = o.dims;
  v.type = o.type;
  v.spacing = o.spacing;
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0)) throw OptionError("spacing", fmt::format("must be positive (reading {})", path));
  v.bytes = detail::read_bytes(path, o.header_bytes, bytes);
  if (o.big_endian == detail::host_is_little_endian())
    detail::byteswap(v.bytes.data(), scalar_size(v.type), static_cast<std::size_t>(v.voxel_count()));
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
