// Boxes of voxels read straight from raw, raw-encoded NRRD, NIfTI and MetaImage files
// (volume_regions.hpp).
#include "adaptiso/volume_regions.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <fmt/format.h>
#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "io_util.hpp"
#include "layout.hpp"

namespace adaptiso {
namespace {

std::string box_text(const VoxelBox& b) {
  return fmt::format("[{}..{}]×[{}..{}]×[{}..{}]", b.lo[0], b.hi[0], b.lo[1], b.hi[1], b.lo[2], b.hi[2]);
}

// Reads exactly n bytes at `at`; false when the file ends first.
bool read_at(int fd, unsigned char* out, std::size_t n, std::uint64_t at) {
  while (n > 0) {
    const ssize_t got = ::pread(fd, out, n, static_cast<off_t>(at));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) return false;
    out += got, n -= static_cast<std::size_t>(got), at += static_cast<std::uint64_t>(got);
  }
  return true;
}

}  // namespace

Volume VolumeRegions::read(const VoxelBox& box) const {
  const Dims& d = header.dims;
  for (int a = 0; a < 3; ++a)
    if (box.lo[a] < 0 || box.hi[a] >= d[a] || box.lo[a] > box.hi[a])
      throw std::invalid_argument(
          fmt::format("VolumeRegions::read: the box {} is not inside the volume's {}×{}×{} voxels", box_text(box), d[0], d[1], d[2]));
  const ScalarType stored = scaling ? scaling->stored : header.type;
  Volume r = make_volume(box.dims(), stored);
  r.spacing = header.spacing, r.direction = header.direction;
  r.origin = header.voxel_to_world(double(box.lo[0]), double(box.lo[1]), double(box.lo[2]));
  const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(fmt::format("{}: cannot open to read the region {}: {}", file, box_text(box), std::strerror(errno)));
  const std::size_t es = scalar_size(stored);
  const Dims n = box.dims();
  // Whole rows of x make each slab of the box one run of bytes.
  const bool whole_rows = box.lo[0] == 0 && n[0] == d[0];
  const std::size_t run = static_cast<std::size_t>(n[0] * (whole_rows ? n[1] : 1)) * es;
  auto* out = reinterpret_cast<unsigned char*>(r.bytes.data());
  bool ok = true;
  for (std::int64_t z = box.lo[2]; ok && z <= box.hi[2]; ++z)
    for (std::int64_t y = box.lo[1]; ok && y <= (whole_rows ? box.lo[1] : box.hi[1]); ++y) {
      const auto voxel = static_cast<std::uint64_t>((z * d[1] + y) * d[0] + box.lo[0]);
      ok = read_at(fd, out, run, offset + voxel * es);
      out += run;
    }
  ::close(fd);
  if (!ok) throw InputError(fmt::format("{}: the region {} reaches past the end of the file (truncated?)", file, box_text(box)));
  if (swap) detail::byteswap(reinterpret_cast<unsigned char*>(r.bytes.data()), es, static_cast<std::size_t>(r.voxel_count()));
  const std::string where = fmt::format("{}, region {}", file, box_text(box));
  check_finite(r, where);
  if (scaling) detail::apply_scaling(r, {scaling->slope, scaling->inter, header.type}, where);
  return r;
}

std::optional<VolumeRegions> open_regions(const std::string& path, const ReadOptions& options) {
  VolumeRegions out;
  if (options.raw) {
    detail::RawLayout l = detail::raw_layout(path, *options.raw);
    out.header = std::move(l.header);
    out.file = path, out.offset = l.offset, out.swap = l.swap;
  } else if (const auto format = detail::volume_format(path); format == detail::VolumeFormat::nifti) {
    detail::NiftiLayout l = detail::nifti_layout(path);
    if (l.gz) return std::nullopt;
    out.header = std::move(l.header);
    out.file = l.file, out.offset = l.offset, out.swap = l.swap;
    if (l.scaling) {
      out.scaling = VolumeRegions::Scaling{out.header.type, l.scaling->slope, l.scaling->inter};
      out.header.type = l.scaling->type;
    }
  } else if (format == detail::VolumeFormat::metaimage) {
    detail::MetaImageLayout l = detail::metaimage_layout(path);
    if (l.compressed || l.files.size() != 1) return std::nullopt;
    out.header = std::move(l.header);
    out.file = l.files[0], out.offset = l.starts[0], out.swap = l.swap;
  } else {
    if (format != detail::VolumeFormat::nrrd) return std::nullopt;
    detail::NrrdLayout l = detail::nrrd_layout(path);
    if (!l.raw || l.files.size() != 1 || l.line_skip != 0) return std::nullopt;
    const std::uint64_t size = detail::file_size_or_throw(l.files[0]), start = std::min(l.data_offset, size);
    const std::uint64_t first = start + detail::raw_data_start(size - start, l.bytes, l.byte_skip, l.files[0]);
    out.header = std::move(l.header);
    out.file = l.files[0], out.offset = first, out.swap = l.swap;
  }
  check_geometry(out.header.dims, out.header.spacing, out.header.origin, out.header.direction, path);
  return out;
}

}  // namespace adaptiso
