// NIfTI-1 and NIfTI-2 reader (.nii, .nii.gz, .hdr/.img) through nifticlib's nifti2 API, which reads
// both versions. scl_slope/scl_inter are applied (values become float32, or float64 for 32-bit
// integer data). Geometry from the sform when set, else the qform, else pixdim.
#include <nifti2_io.h>

#include <fmt/format.h>
#include <cmath>
#include <filesystem>
#include <memory>
#include <mutex>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

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
struct NimFree {
  void operator()(nifti_image* p) const { nifti_image_free(p); }
};
}  // namespace

Volume read_nifti(const std::string& path) {
  detail::file_size_or_throw(path);
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
  Dims dims{nim->nx, nim->ny, nim->dim[0] >= 3 ? nim->nz : 1};
  std::size_t bytes = checked_volume_bytes(dims, scalar_size(*type), path);
  // Bound the allocation by what the image file can hold.
  std::string img = nim->iname ? nim->iname : path;
  std::uint64_t on_disk = detail::file_size_or_throw(img);
  bool gz = img.size() > 3 && img.ends_with(".gz");
  std::uint64_t offset = static_cast<std::uint64_t>(std::max<std::int64_t>(nim->iname_offset, 0));
  std::uint64_t avail = gz ? detail::max_inflated_size(on_disk) : (on_disk > offset ? on_disk - offset : 0);
  if (bytes > avail)
    throw InputError(fmt::format("{}: header says {}x{}x{} {} ({} bytes) but the file holds only {} bytes", path, dims[0], dims[1], dims[2],
                                 scalar_name(*type), bytes, avail));
  if (nifti_image_load(nim.get()) != 0 || !nim->data) throw InputError(fmt::format("{}: NIfTI data is truncated or unreadable", path));

  Volume v;
  v.dims = dims;
  v.type = *type;
  const auto* src = static_cast<const unsigned char*>(nim->data);
  v.bytes.assign(src, src + bytes);
  check_finite(v, path);

  const double slope = nim->scl_slope, inter = nim->scl_inter;
  if (std::isfinite(slope) && slope != 0 && (slope != 1 || inter != 0)) {
    if (!std::isfinite(inter)) throw InputError(fmt::format("{}: scl_inter is not finite", path));
    bool wide = v.type == ScalarType::u32 || v.type == ScalarType::i32 || v.type == ScalarType::f64;
    Volume s = make_volume(dims, wide ? ScalarType::f64 : ScalarType::f32);
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) s.set(i, v.at(i) * slope + inter);
    s.bytes.swap(v.bytes);
    v.type = s.type;
    check_finite(v, path);
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
  return v;
}

}  // namespace adaptiso
