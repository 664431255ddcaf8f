// NIfTI-1 and NIfTI-2 reader (.nii, .nii.gz, .hdr/.img) through nifticlib's nifti2 API, which reads
// both versions. scl_slope/scl_inter are applied (values become float32, or float64 for 32-bit
// integer data). Geometry from the sform when set, else the qform, else pixdim.
#include <nifti2_io.h>

#include <fmt/format.h>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"
#include "layout.hpp"

namespace adaptiso {
namespace {
std::mutex nifti_mutex;

std::optional<ScalarType> from_nifti(int dt) {
  switch (dt) {
    case DT_UINT8:
      return ScalarType::u8;
    case DT_INT8:
      return ScalarType::i8;
    case DT_UINT16:
      return ScalarType::u16;
    case DT_INT16:
      return ScalarType::i16;
    case DT_UINT32:
      return ScalarType::u32;
    case DT_INT32:
      return ScalarType::i32;
    case DT_FLOAT32:
      return ScalarType::f32;
    case DT_FLOAT64:
      return ScalarType::f64;
    default:
      return std::nullopt;
  }
}
// The image's bytes, from the .nii after vox_offset or from the .img, gzip'ed or not; the gzip
// stream must be whole (its length and CRC trailer checked).
std::vector<unsigned char> image_bytes(const detail::NiftiLayout& l) {
  if (!l.gz) return detail::read_bytes(l.file, l.offset, l.bytes);  // throws when the file is truncated
  detail::check_fits(l.file, l.offset + l.bytes);
  const auto compressed = detail::read_bytes(l.file, 0, detail::file_size_or_throw(l.file));
  std::vector<unsigned char> all(l.offset + l.bytes);
  detail::inflate_exact(compressed.data(), compressed.size(), all.data(), all.size(), l.file, /*allow_trailing=*/true);
  all.erase(all.begin(), all.begin() + static_cast<long>(l.offset));  // the header: no second copy of the data
  return all;
}

// nifticlib recurses without end on a NIfTI-2 header cut short, prints its own errors on others,
// and trusts the rest: the header's size, magic, dimensions, type and data offset are checked here
// first. Returns the header's vox_offset (NIfTI-1 stores a float, which nifticlib converts to an
// integer: 1e12 overflowed there and the data was read from just after the header).
double check_header(const std::string& path, std::uint64_t size) {
  const bool gz = detail::lower(path).ends_with(".gz");
  std::vector<unsigned char> h = detail::read_bytes(path, 0, std::min<std::uint64_t>(size, gz ? 1 << 16 : 540));
  if (gz) h = detail::inflate_prefix(h.data(), h.size(), 540);
  auto fail = [&](const std::string& why) { throw InputError(fmt::format("{}: not a valid NIfTI file ({})", path, why)); };
  if (h.size() < 4) fail("shorter than its header");
  std::int32_t sizeof_hdr;
  std::memcpy(&sizeof_hdr, h.data(), 4);
  const bool swap = sizeof_hdr != 348 && sizeof_hdr != 540;
  if (swap) detail::byteswap(reinterpret_cast<unsigned char*>(&sizeof_hdr), 4, 1);
  if (sizeof_hdr != 348 && sizeof_hdr != 540) fail(fmt::format("header size {} is neither 348 nor 540", sizeof_hdr));
  if (h.size() < static_cast<std::size_t>(sizeof_hdr)) fail(fmt::format("the file ends inside its {}-byte header", sizeof_hdr));
  auto get = [&](std::size_t at, auto value) {
    std::memcpy(&value, &h[at], sizeof value);
    if (swap) detail::byteswap(reinterpret_cast<unsigned char*>(&value), sizeof value, 1);
    return static_cast<std::int64_t>(value);
  };
  const bool v2 = sizeof_hdr == 540;
  const std::string magic(reinterpret_cast<const char*>(&h[v2 ? 4 : 344]), 4);
  const bool analyze = !v2 && magic == std::string(4, '\0') && detail::lower(path).ends_with(".hdr");
  if (!analyze && magic != (v2 ? std::string("n+2\0", 4) : std::string("n+1\0", 4)) &&
      magic != (v2 ? std::string("ni2\0", 4) : std::string("ni1\0", 4)))
    fail("bad magic");
  const std::int64_t datatype = v2 ? get(12, std::int16_t{}) : get(70, std::int16_t{});
  if (!from_nifti(static_cast<int>(datatype)))
    throw InputError(fmt::format("{}: NIfTI datatype {} is not supported (8/16/32-bit integers, float32, float64)", path, datatype));
  const std::int64_t ndim = v2 ? get(16, std::int64_t{}) : get(40, std::int16_t{});
  if (ndim < 1 || ndim > 7) fail(fmt::format("dim[0] = {}", ndim));
  for (int a = 1; a <= ndim; ++a) {
    const std::int64_t d =
        v2 ? get(16 + 8 * static_cast<std::size_t>(a), std::int64_t{}) : get(40 + 2 * static_cast<std::size_t>(a), std::int16_t{});
    if (d < 1) fail(fmt::format("dim[{}] = {}", a, d));
  }
  double vox_offset = 0;
  if (v2) {
    vox_offset = static_cast<double>(get(168, std::int64_t{}));
  } else {
    float f;
    std::memcpy(&f, &h[108], 4);
    if (swap) detail::byteswap(reinterpret_cast<unsigned char*>(&f), 4, 1);
    vox_offset = f;
  }
  if (!(vox_offset >= 0) || !std::isfinite(vox_offset)) fail(fmt::format("vox_offset {:.6g} is not an offset", vox_offset));
  // In a .nii the data follows in the same file, which must reach that far (a .hdr's data is in
  // its .img, checked when read).
  const bool same_file = magic == (v2 ? std::string("n+2\0", 4) : std::string("n+1\0", 4));
  const double reach = static_cast<double>(gz ? detail::max_inflated_size(size) : size);
  if (same_file && vox_offset > reach)
    throw InputError(
        fmt::format("{}: vox_offset {:.6g} is past the end of the file ({} bytes{})", path, vox_offset, size, gz ? " compressed" : ""));
  return vox_offset;
}

// nifticlib looks for the .img beside a .hdr by opening candidates; a FIFO there would block it.
void refuse_special_image_files(const std::string& path) {
  namespace fs = std::filesystem;
  const std::string l = detail::lower(path);
  if (!l.ends_with(".hdr") && !l.ends_with(".hdr.gz")) return;
  const std::string stem = path.substr(0, path.size() - (l.ends_with(".gz") ? 7 : 4));
  for (const char* ext : {".img", ".img.gz", ".IMG", ".IMG.gz"}) {
    std::error_code ec;
    const auto st = fs::status(stem + ext, ec);
    if (fs::exists(st)) detail::file_size_or_throw(stem + ext);  // refuses what is not a regular file
  }
}

struct NimFree {
  void operator()(nifti_image* p) const { nifti_image_free(p); }
};
}  // namespace

namespace detail {

NiftiLayout nifti_layout(const std::string& path) {
  const double vox_offset = check_header(path, detail::file_size_or_throw(path));
  refuse_special_image_files(path);
  std::lock_guard lock(nifti_mutex);
  nifti_set_debug_level(0);
  std::unique_ptr<nifti_image, NimFree> nim(nifti_image_read(path.c_str(), 0));
  if (!nim) throw InputError(fmt::format("{}: not a readable NIfTI-1/NIfTI-2 file", path));
  auto type = from_nifti(nim->datatype);
  if (!type)
    throw InputError(fmt::format("{}: NIfTI datatype {} ({}) is not supported", path, nim->datatype, nifti_datatype_string(nim->datatype)));
  for (int a = 4; a <= 7; ++a)
    if (nim->dim[0] >= a && nim->dim[a] > 1)
      throw InputError(
          fmt::format("{}: NIfTI has {} dimensions with size > 1 beyond x,y,z; adaptiso reads 3D scalar volumes", path, nim->dim[0]));
  NiftiLayout l;
  Volume& v = l.header;
  v.dims = {nim->nx, nim->ny, nim->dim[0] >= 3 ? nim->nz : 1};
  v.type = *type;
  const std::size_t es = scalar_size(*type);
  l.bytes = checked_volume_bytes(v.dims, es, path);

  l.file = nim->iname ? nim->iname : path;
  const std::uint64_t on_disk = detail::file_size_or_throw(l.file);
  if (nim->iname_offset < 0) throw InputError(fmt::format("{}: vox_offset is negative", path));
  // nifticlib raises a .nii's offset to its header's size; past that it must have read the
  // header's own value, or it converted it wrongly.
  if (vox_offset > static_cast<double>(nim->iname_offset) + 1)
    throw InputError(
        fmt::format("{}: vox_offset {:.6g} cannot be read (the NIfTI library made it {})", path, vox_offset, nim->iname_offset));
  l.offset = static_cast<std::uint64_t>(nim->iname_offset);
  l.gz = detail::lower(l.file).ends_with(".gz");
  if (!l.gz && l.offset > on_disk)
    throw InputError(fmt::format("{}: vox_offset {} is past the end of the file ({} bytes)", path, l.offset, on_disk));
  if (l.gz && (l.offset > detail::max_inflated_size(on_disk) || l.bytes > detail::max_inflated_size(on_disk) - l.offset))
    throw InputError(fmt::format("{}: header says {} bytes of data but the compressed file can hold at most {}", path, l.bytes,
                                 detail::max_inflated_size(on_disk)));
  // nifti_image_load would turn NaN/Inf into 0 silently; the bytes are read here instead and keep
  // them for check_finite to refuse, as for every other format.
  l.swap = es > 1 && nim->byteorder != nifti_short_order();

  const double slope = nim->scl_slope, inter = nim->scl_inter;
  if (std::isfinite(slope) && slope != 0 && (slope != 1 || inter != 0)) {
    if (!std::isfinite(inter)) throw InputError(fmt::format("{}: scl_inter is not finite", path));
    const bool wide = v.type == ScalarType::u32 || v.type == ScalarType::i32 || v.type == ScalarType::f64;
    l.scaling = NiftiScaling{slope, inter, wide ? ScalarType::f64 : ScalarType::f32};
  }

  // Geometry: column a of the 3×3 part of the (s|q)form is spacing_a × direction_a.
  const nifti_dmat44* m = nim->sform_code > 0 ? &nim->sto_xyz : nim->qform_code > 0 ? &nim->qto_xyz : nullptr;
  if (m) {
    for (int a = 0; a < 3; ++a) {
      double len = std::sqrt(m->m[0][a] * m->m[0][a] + m->m[1][a] * m->m[1][a] + m->m[2][a] * m->m[2][a]);
      if (!(len > 0)) throw InputError(fmt::format("{}: orientation matrix has a zero column", path));
      v.spacing[a] = len;
      for (int r = 0; r < 3; ++r) v.direction[3 * r + a] = m->m[r][a] / len;
      v.origin[a] = m->m[a][3];
    }
  } else {
    double p[3] = {nim->dx, nim->dy, nim->dz};
    for (int a = 0; a < 3; ++a) v.spacing[a] = std::isfinite(p[a]) && p[a] != 0 ? std::abs(p[a]) : 1.0;
  }
  return l;
}

void apply_scaling(Volume& v, const NiftiScaling& s, const std::string& where) {
  Volume out = make_volume(v.dims, s.type);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) out.set(i, v.at(i) * s.slope + s.inter);
  v.bytes.swap(out.bytes);
  v.type = s.type;
  check_finite(v, where);
}

}  // namespace detail

Volume read_nifti(const std::string& path) {
  const detail::NiftiLayout l = detail::nifti_layout(path);
  Volume v = l.header;
  v.bytes = image_bytes(l);
  if (l.swap) detail::byteswap(v.bytes.data(), scalar_size(v.type), l.bytes / scalar_size(v.type));
  check_finite(v, path);
  if (l.scaling) detail::apply_scaling(v, *l.scaling, path);
  return v;
}

}  // namespace adaptiso
