// Boxes of voxels read straight from raw, raw-encoded NRRD, NIfTI and MetaImage files, and slabs
// inflated from compressed ones (volume_regions.hpp).
#include "adaptiso/volume_regions.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <bzlib.h>
#include <fmt/format.h>
#include <zlib.h>
#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "boxes.hpp"
#include "dicom_series.hpp"
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

void check_inside(const char* who, const VoxelBox& box, const Dims& d) {
  for (int a = 0; a < 3; ++a)
    if (box.lo[a] < 0 || box.hi[a] >= d[a] || box.lo[a] > box.hi[a])
      throw std::invalid_argument(
          fmt::format("{}: the box {} is not inside the volume's {}×{}×{} voxels", who, box_text(box), d[0], d[1], d[2]));
}

// A box's samples as stored (`stored` type), with the volume's geometry and the origin at the box's
// first voxel.
Volume stored_box(const Volume& header, const VoxelBox& box, const std::optional<VolumeRegions::Scaling>& scaling) {
  Volume r = make_volume(box.dims(), scaling ? scaling->stored : header.type);
  r.spacing = header.spacing, r.direction = header.direction;
  r.origin = header.voxel_to_world(double(box.lo[0]), double(box.lo[1]), double(box.lo[2]));
  return r;
}

// A NIfTI layout's scaling as the readers keep it: the header takes the scaled type, the scaling
// the stored one.
std::optional<VolumeRegions::Scaling> take_scaling(Volume& header, const std::optional<detail::NiftiScaling>& s) {
  if (!s) return std::nullopt;
  const VolumeRegions::Scaling out{header.type, s->slope, s->inter};
  header.type = s->type;
  return out;
}

// Stored samples as read_volume makes them: this machine's byte order, finite, scaled.
void finish(Volume& r, bool swap, const std::optional<VolumeRegions::Scaling>& scaling, ScalarType type, const std::string& where) {
  if (swap)
    detail::byteswap(reinterpret_cast<unsigned char*>(r.bytes.data()), scalar_size(r.type), static_cast<std::size_t>(r.voxel_count()));
  check_finite(r, where);
  if (scaling) detail::apply_scaling(r, {scaling->slope, scaling->inter, type}, where);
}

}  // namespace

namespace detail {

void copy_box(const std::uint8_t* src, const Dims& dims, const VoxelBox& from, std::size_t size, std::uint8_t* dst) {
  const Dims n = from.dims();
  const auto row = static_cast<std::size_t>(n[0]) * size;
  for (std::int64_t z = 0; z < n[2]; ++z)
    for (std::int64_t y = 0; y < n[1]; ++y) {
      const std::int64_t at = from.lo[0] + dims[0] * ((from.lo[1] + y) + dims[1] * (from.lo[2] + z));
      std::memcpy(dst + static_cast<std::size_t>(y + n[1] * z) * row, src + static_cast<std::size_t>(at) * size, row);
    }
}

Volume copy_box(const Volume& v, const VoxelBox& box) {
  Volume r = stored_box(v, box, std::nullopt);
  copy_box(reinterpret_cast<const std::uint8_t*>(v.bytes.data()), v.dims, box, scalar_size(v.type),
           reinterpret_cast<std::uint8_t*>(r.bytes.data()));
  return r;
}

}  // namespace detail

Volume VolumeRegions::read(const VoxelBox& box) const {
  const Dims& d = header.dims;
  check_inside("VolumeRegions::read", box, d);
  Volume r = stored_box(header, box, scaling);
  const ScalarType stored = r.type;
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
  finish(r, swap, scaling, header.type, fmt::format("{}, region {}", file, box_text(box)));
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
    detail::check_holds(l.file, l.offset, l.bytes);  // as read_volume refuses it
    out.header = std::move(l.header);
    out.file = l.file, out.offset = l.offset, out.swap = l.swap;
    out.scaling = take_scaling(out.header, l.scaling);
  } else if (format == detail::VolumeFormat::metaimage) {
    detail::MetaImageLayout l = detail::metaimage_layout(path);
    if (l.compressed || l.files.size() != 1) return std::nullopt;
    detail::check_holds(l.files[0], l.starts[0], l.stored[0]);
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

// ---- slabs of a compressed stream ----

namespace {

// The decompressor behind a stream: zlib (zlib or gzip streams, as read_volume's inflate) or
// bzip2, driven the same way.
class Decoder {
public:
  enum class Step { progress, end, stuck, corrupt };  // stuck: nothing more without more input

  Decoder() = default;
  Decoder(const Decoder&) = delete;
  Decoder& operator=(const Decoder&) = delete;
  ~Decoder() { close(); }

  bool bzip2 = false;
  bool open() const { return open_; }
  void restart() {
    close();
    if (bzip2) {
      bz_ = bz_stream{};
      if (BZ2_bzDecompressInit(&bz_, 0, 0) != BZ_OK) throw std::runtime_error("bzip2: init failed");
    } else {
      zs_ = z_stream{};
      if (inflateInit2(&zs_, 15 + 32) != Z_OK) throw std::runtime_error("zlib: inflateInit failed");
    }
    open_ = true, ended_ = false;
  }
  std::size_t input_left() const { return bzip2 ? bz_.avail_in : zs_.avail_in; }
  void give(unsigned char* p, std::size_t n) {
    if (bzip2)
      bz_.next_in = reinterpret_cast<char*>(p), bz_.avail_in = static_cast<unsigned>(n);
    else
      zs_.next_in = p, zs_.avail_in = static_cast<uInt>(n);
  }
  // Decodes into out[0, n) (n < 2^32); n becomes the bytes produced.
  Step run(unsigned char* out, std::size_t& n) {
    if (ended_) return n = 0, Step::end;  // bzip2 ends with the last byte, zlib after it; neither runs again
    const Step step = decode(out, n);
    ended_ = step == Step::end;
    return step;
  }
  const std::string& message() const { return message_; }

private:
  Step decode(unsigned char* out, std::size_t& n) {
    if (bzip2) {
      bz_.next_out = reinterpret_cast<char*>(out), bz_.avail_out = static_cast<unsigned>(n);
      const unsigned in_before = bz_.avail_in;
      const int rc = BZ2_bzDecompress(&bz_);
      n -= bz_.avail_out;
      if (rc == BZ_STREAM_END) return Step::end;
      if (rc != BZ_OK) return message_ = fmt::format("bzip2 code {}", rc), Step::corrupt;
      return n == 0 && bz_.avail_in == in_before ? Step::stuck : Step::progress;
    }
    zs_.next_out = out, zs_.avail_out = static_cast<uInt>(n);
    const int rc = inflate(&zs_, Z_NO_FLUSH);
    n -= zs_.avail_out;
    if (rc == Z_STREAM_END) return Step::end;
    if (rc == Z_BUF_ERROR) return Step::stuck;
    if (rc != Z_OK) return message_ = zs_.msg ? zs_.msg : "corrupt data", Step::corrupt;
    return Step::progress;
  }
  void close() {
    if (open_ && bzip2) BZ2_bzDecompressEnd(&bz_);
    if (open_ && !bzip2) inflateEnd(&zs_);
    open_ = false;
  }
  bool open_ = false, ended_ = false;
  z_stream zs_{};
  bz_stream bz_{};
  std::string message_;
};

}  // namespace

struct VolumeStream::State {
  Volume header;
  std::string file;
  std::uint64_t first = 0, end = 0;  // the compressed bytes in the file
  std::uint64_t skip = 0;            // inflated bytes before the first sample
  bool swap = false;
  std::optional<VolumeRegions::Scaling> scaling;
  std::size_t slice = 0;  // bytes of one stored slice

  int fd = -1;
  Decoder decoder;
  bool broken = false;           // a hold failed part way: where the stream stands is unknown
  std::uint64_t read_to = 0;     // the next compressed byte to feed
  std::int64_t next = 0;         // the first slice not inflated yet
  std::uint64_t skipped = 0;     // of `skip`
  std::int64_t z0 = 0, z1 = -1;  // the slices held
  std::vector<unsigned char> held, in;
  std::uint64_t inflations = 0;
  bool trailing = false;                     // data after the samples is allowed (as read_volume allows it: NIfTI)
  std::optional<detail::DicomSeries> dicom;  // slices read from their files instead of a stream

  // A DICOM series: the slices held that are asked for again are kept, the others read from
  // their files, in any order. Nothing changes when a file fails.
  void hold_files(std::int64_t lo, std::int64_t hi) {
    std::vector<unsigned char> next_held(static_cast<std::size_t>(hi - lo + 1) * slice);
    std::int64_t keep_lo = std::max(lo, z0), keep_hi = std::min(hi, z1);
    if (keep_lo <= keep_hi)
      std::memcpy(next_held.data() + static_cast<std::size_t>(keep_lo - lo) * slice,
                  held.data() + static_cast<std::size_t>(keep_lo - z0) * slice, static_cast<std::size_t>(keep_hi - keep_lo + 1) * slice);
    else
      keep_lo = hi + 1, keep_hi = hi;
    if (lo < keep_lo) detail::read_dicom_slices(*dicom, lo, keep_lo - 1, next_held.data());
    if (keep_hi < hi)
      detail::read_dicom_slices(*dicom, keep_hi + 1, hi, next_held.data() + static_cast<std::size_t>(keep_hi + 1 - lo) * slice);
    held.swap(next_held);
    z0 = lo, z1 = hi;
  }

  ~State() {
    if (fd >= 0) ::close(fd);
  }

  void restart() {
    decoder.restart();
    read_to = first, next = 0, skipped = 0, z0 = 0, z1 = -1, broken = false;
    ++inflations;
  }

  // More compressed bytes for the decoder, when it has used up those it had and the file has more.
  // (It may still hold output and the trailer's bytes when it has taken every input byte.)
  void feed(const std::string& what) {
    if (decoder.input_left() > 0 || read_to >= end) return;
    const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(in.size(), end - read_to));
    ssize_t got = -1;
    while (got < 0) {
      got = ::pread(fd, in.data(), want, static_cast<off_t>(read_to));
      if (got < 0 && errno != EINTR) throw InputError(fmt::format("{}: cannot read before {}: {}", file, what, std::strerror(errno)));
    }
    if (got == 0) throw InputError(fmt::format("{}: the file ends before {} (truncated?)", file, what));
    read_to += static_cast<std::uint64_t>(got);
    decoder.give(in.data(), static_cast<std::size_t>(got));
  }

  // The decoder's step: stuck with no bytes left in the file is a stream cut short.
  void check(Decoder::Step step, const std::string& what) const {
    if (step == Decoder::Step::stuck && decoder.input_left() == 0 && read_to >= end)
      throw InputError(fmt::format("{}: the compressed stream is cut short before {}", file, what));
    if (step == Decoder::Step::corrupt)
      throw InputError(fmt::format("{}: compressed data is corrupt before {} ({})", file, what, decoder.message()));
  }

  // After the last sample: the stream must end there, its check value (gzip's CRC-32 and length,
  // zlib's Adler-32, bzip2's CRCs) verified by the decoder, as read_volume verifies it; without
  // this a corrupt stream whose samples still decode would pass. More data than the samples is
  // refused as read_volume refuses it, or decoded and dropped where it allows it (trailing).
  void finish() {
    unsigned char scratch[1 << 14];
    const std::string what = "its end (the check value after the last sample)";
    for (Decoder::Step step = Decoder::Step::progress; step != Decoder::Step::end;) {
      feed(what);
      std::size_t n = sizeof scratch;
      step = decoder.run(scratch, n);
      if (n > 0 && !trailing)
        throw InputError(fmt::format("{}: compressed data holds more than the expected {} bytes", file, skip + slice * header.dims[2]));
      check(step, what);
    }
  }

  // The next n decoded bytes into out (nullptr: dropped); `what` names them in errors.
  void pull(unsigned char* out, std::size_t n, const std::string& what) {
    unsigned char scratch[1 << 14];
    while (n > 0) {
      feed(what);
      std::size_t got = std::min(n, out ? std::size_t{1} << 30 : sizeof scratch);
      const Decoder::Step step = decoder.run(out ? out : scratch, got);
      if (out) out += got;
      n -= got;
      if (step == Decoder::Step::end && n > 0) throw InputError(fmt::format("{}: the compressed stream ends before {}", file, what));
      check(step, what);
    }
  }
};

VolumeStream::VolumeStream(std::unique_ptr<State> s) : s_(std::move(s)) {}
VolumeStream::VolumeStream(VolumeStream&&) noexcept = default;
VolumeStream& VolumeStream::operator=(VolumeStream&&) noexcept = default;
VolumeStream::~VolumeStream() = default;
const Volume& VolumeStream::header() const { return s_->header; }
std::uint64_t VolumeStream::inflations() const { return s_->inflations; }
bool VolumeStream::slice_files() const { return s_->dicom.has_value(); }

void VolumeStream::hold(std::int64_t z0, std::int64_t z1) {
  State& s = *s_;
  if (z0 < 0 || z1 >= s.header.dims[2] || z0 > z1)
    throw std::invalid_argument(fmt::format("VolumeStream::hold: slices {}..{} are not inside the volume's {}", z0, z1, s.header.dims[2]));
  if (z0 >= s.z0 && z1 <= s.z1) return;
  if (s.dicom) return s.hold_files(z0, z1);
  if (!s.decoder.open() || s.broken || z0 < s.z0) s.restart();  // the slices before z0 are gone
  // Keep the held slices from z0 on (moved to the front, in place: one slab's memory, not two),
  // inflate the rest up to z1.
  std::int64_t have = z0;
  if (s.z1 >= z0) {
    const std::int64_t to = std::min(z1, s.z1);
    std::memmove(s.held.data(), s.held.data() + static_cast<std::size_t>(z0 - s.z0) * s.slice,
                 static_cast<std::size_t>(to - z0 + 1) * s.slice);
    have = to + 1;
  }
  s.z0 = 0, s.z1 = -1, s.broken = true;
  s.held.resize(static_cast<std::size_t>(z1 - z0 + 1) * s.slice);
  if (s.skipped < s.skip) s.pull(nullptr, s.skip - s.skipped, "the first sample"), s.skipped = s.skip;
  for (; s.next < z0; ++s.next) s.pull(nullptr, s.slice, fmt::format("slice {}", s.next + 1));
  for (; s.next <= z1; ++s.next) {
    if (s.next < have) continue;
    s.pull(s.held.data() + static_cast<std::size_t>(s.next - z0) * s.slice, s.slice, fmt::format("the end of slice {}", s.next));
    if (s.next == s.header.dims[2] - 1) s.finish();
  }
  s.z0 = z0, s.z1 = z1, s.broken = false;
}

Volume VolumeStream::read(const VoxelBox& box) const {
  const State& s = *s_;
  check_inside("VolumeStream::read", box, s.header.dims);
  if (box.lo[2] < s.z0 || box.hi[2] > s.z1)
    throw std::invalid_argument(
        fmt::format("VolumeStream::read: the box {} is outside the slices held ({}..{})", box_text(box), s.z0, s.z1));
  Volume r = stored_box(s.header, box, s.scaling);
  const std::size_t es = scalar_size(r.type), row = static_cast<std::size_t>(box.dims()[0]) * es;
  const Dims& d = s.header.dims;
  auto* out = reinterpret_cast<unsigned char*>(r.bytes.data());
  for (std::int64_t z = box.lo[2]; z <= box.hi[2]; ++z)
    for (std::int64_t y = box.lo[1]; y <= box.hi[1]; ++y, out += row)
      std::memcpy(out, s.held.data() + static_cast<std::size_t>(((z - s.z0) * d[1] + y) * d[0] + box.lo[0]) * es, row);
  finish(r, s.swap, s.scaling, s.header.type, fmt::format("{}, region {}", s.file, box_text(box)));
  return r;
}

std::optional<VolumeStream> open_stream(const std::string& path, const ReadOptions& options) {
  if (options.raw) return std::nullopt;
  auto s = std::make_unique<VolumeStream::State>();
  const auto format = detail::volume_format(path);
  if (format == detail::VolumeFormat::nifti) {
    detail::NiftiLayout l = detail::nifti_layout(path);
    if (!l.gz) return std::nullopt;
    s->header = std::move(l.header);
    s->file = l.file, s->skip = l.offset, s->swap = l.swap;
    s->end = detail::file_size_or_throw(l.file);
    s->scaling = take_scaling(s->header, l.scaling);
    s->trailing = true;
  } else if (format == detail::VolumeFormat::metaimage) {
    detail::MetaImageLayout l = detail::metaimage_layout(path);
    if (!l.compressed || l.files.size() != 1) return std::nullopt;
    s->header = std::move(l.header);
    s->file = l.files[0], s->first = l.starts[0], s->end = l.starts[0] + l.stored[0], s->swap = l.swap;
  } else if (format == detail::VolumeFormat::nrrd) {
    detail::NrrdLayout l = detail::nrrd_layout(path);
    if ((l.encoding != nrrdEncodingGzip && l.encoding != nrrdEncodingBzip2) || l.files.size() != 1 || l.line_skip != 0 || l.byte_skip < 0)
      return std::nullopt;
    s->decoder.bzip2 = l.encoding == nrrdEncodingBzip2;
    s->header = std::move(l.header);
    s->file = l.files[0], s->skip = static_cast<std::uint64_t>(l.byte_skip), s->swap = l.swap;
    s->end = detail::file_size_or_throw(l.files[0]);
    s->first = l.attached ? std::min(l.data_offset, s->end) : 0;
  } else if (format == detail::VolumeFormat::dicom) {
    s->dicom = detail::open_dicom_series(path);
    if (!s->dicom) return std::nullopt;  // a multi-frame file: read whole
    s->header = s->dicom->header;
    s->file = path;
    check_geometry(s->header.dims, s->header.spacing, s->header.origin, s->header.direction, path);
    s->slice = static_cast<std::size_t>(s->header.dims[0] * s->header.dims[1]) * scalar_size(s->header.type);
    return VolumeStream(std::move(s));
  } else {
    return std::nullopt;
  }
  check_geometry(s->header.dims, s->header.spacing, s->header.origin, s->header.direction, path);
  const Dims& d = s->header.dims;
  s->slice = static_cast<std::size_t>(d[0] * d[1]) * scalar_size(s->scaling ? s->scaling->stored : s->header.type);
  s->fd = ::open(s->file.c_str(), O_RDONLY | O_CLOEXEC);
  if (s->fd < 0) throw InputError(fmt::format("{}: cannot open: {}", s->file, std::strerror(errno)));
  s->in.resize(1 << 20);
  return VolumeStream(std::move(s));
}

RegionReader::RegionReader(const std::string& path, const ReadOptions& options) {
  regions_ = open_regions(path, options);
  if (!regions_) stream_ = open_stream(path, options);
  if (!regions_ && !stream_) whole_ = read_volume(path, options);
}

const Volume& RegionReader::header() const { return regions_ ? regions_->header : stream_ ? stream_->header() : *whole_; }

Volume RegionReader::read(const VoxelBox& box) const {
  if (regions_) return regions_->read(box);
  if (stream_) return stream_->read(box);
  check_inside("RegionReader::read", box, whole_->dims);
  return detail::copy_box(*whole_, box);
}

void RegionReader::hold(std::int64_t z0, std::int64_t z1) {
  if (stream_) stream_->hold(z0, z1);
}

namespace {
const char* route_name(bool regions, const std::optional<VolumeStream>& stream) {
  if (regions) return "regions";
  if (stream) return stream->slice_files() ? "slabs of the slice files" : "slabs of the stream";
  return "whole volume";
}
}  // namespace

const char* RegionReader::route() const { return route_name(regions_.has_value(), stream_); }

const char* RegionReader::route_of(const std::string& path, const ReadOptions& options) {
  if (open_regions(path, options)) return route_name(true, std::nullopt);
  return route_name(false, open_stream(path, options));
}

}  // namespace adaptiso
