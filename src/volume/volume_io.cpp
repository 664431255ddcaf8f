// Format dispatch by path (extension, folder, then magic bytes) and the NRRD writer.
#include <zlib.h>

#include <fmt/format.h>
#include <filesystem>
#include <sstream>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

namespace adaptiso {

namespace detail {

VolumeFormat volume_format(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(fmt::format("{}: no such file or folder", path));
  if (fs::is_directory(path, ec)) return VolumeFormat::dicom;
  const std::string l = lower(path);
  auto ends = [&](std::string_view s) { return l.ends_with(s); };
  if (ends(".tar.gz") || ends(".tgz") || ends(".tar") || ends(".zip")) return VolumeFormat::archive;
  if (ends(".nrrd") || ends(".nhdr")) return VolumeFormat::nrrd;
  if (ends(".nii") || ends(".nii.gz") || ends(".hdr")) return VolumeFormat::nifti;
  if (ends(".mha") || ends(".mhd")) return VolumeFormat::metaimage;
  if (ends(".vti")) return VolumeFormat::vti;
  if (ends(".vtk")) return VolumeFormat::legacy_vtk;
  if (ends(".dcm")) return VolumeFormat::dicom;
  if (ends(".raw") || ends(".img") || ends(".bin")) return VolumeFormat::raw_samples;
  // Unknown extension: look at the first bytes.
  std::uint64_t size = file_size_or_throw(path);
  auto head = read_bytes(path, 0, std::min<std::uint64_t>(size, 352));
  std::string h(head.begin(), head.end());
  if (h.starts_with("NRRD000")) return VolumeFormat::nrrd;
  if (h.starts_with("# vtk DataFile")) return VolumeFormat::legacy_vtk;
  if (h.find("<VTKFile") != std::string::npos) return VolumeFormat::vti;
  if (h.size() >= 348 && (h.compare(344, 4, std::string("n+1\0", 4)) == 0)) return VolumeFormat::nifti;
  if (h.size() >= 8 && (h.compare(4, 4, std::string("n+2\0", 4)) == 0)) return VolumeFormat::nifti;
  if (h.size() >= 132 && h.compare(128, 4, "DICM") == 0) return VolumeFormat::dicom;
  if (h.find("ElementDataFile") != std::string::npos || h.starts_with("ObjectType") || h.starts_with("NDims"))
    return VolumeFormat::metaimage;
  return VolumeFormat::unknown;
}

}  // namespace detail

namespace {

Volume read_any(const std::string& path, const ReadOptions& options) {
  if (options.raw) return read_raw(path, *options.raw);
  using F = detail::VolumeFormat;
  switch (detail::volume_format(path)) {
    case F::dicom:
      return read_dicom_folder(path);
    case F::archive:
      throw InputError(fmt::format("{}: is an archive; unpack it first (e.g. tar xzf {}) and pass the folder of DICOM files", path,
                                   std::filesystem::path(path).filename().string()));
    case F::nrrd:
      return read_nrrd(path);
    case F::nifti:
      return read_nifti(path);
    case F::metaimage:
      return read_metaimage(path);
    case F::vti:
      return read_vti(path);
    case F::legacy_vtk:
      return read_legacy_vtk(path);
    case F::raw_samples:
      throw OptionError(
          "dims",
          fmt::format("{} holds raw samples: give its dimensions and element type (and byte order, spacing, header size as needed)", path));
    case F::unknown:
      break;
  }
  throw InputError(
      fmt::format("{}: unknown volume format (expected .nrrd .nhdr .nii[.gz] .mha .mhd .vti .vtk, a DICOM folder, or raw samples with "
                  "their dimensions and type)",
                  path));
}

}  // namespace

Volume read_volume(const std::string& path, const ReadOptions& options) {
  Volume v = read_any(path, options);
  check_geometry(v, path);
  return v;
}

void write_nrrd(const Volume& v, const std::string& path, bool gzip) {
  std::ostringstream hdr;
  static const char* names[] = {"uint8", "int8", "uint16", "int16", "uint32", "int32", "float", "double"};
  hdr << "NRRD0004\n# written by adaptiso\n";
  hdr << "type: " << names[static_cast<int>(v.type)] << "\ndimension: 3\n";
  hdr << fmt::format("sizes: {} {} {}\n", v.dims[0], v.dims[1], v.dims[2]);
  if (!v.is_oblique() && v.origin == Vec3{0, 0, 0}) {
    hdr << fmt::format("spacings: {} {} {}\n", v.spacing[0], v.spacing[1], v.spacing[2]);
  } else {
    hdr << "space dimension: 3\nspace directions:";
    for (int a = 0; a < 3; ++a)
      hdr << fmt::format(" ({},{},{})", v.direction[a] * v.spacing[a], v.direction[3 + a] * v.spacing[a],
                         v.direction[6 + a] * v.spacing[a]);
    hdr << fmt::format("\nspace origin: ({},{},{})\n", v.origin[0], v.origin[1], v.origin[2]);
  }
  hdr << "endian: " << (detail::host_is_little_endian() ? "little" : "big") << "\n";
  hdr << "encoding: " << (gzip ? "gzip" : "raw") << "\n\n";
  write_file_atomically(path, [&](std::ostream& out) {
    out << hdr.str();
    if (!gzip) {
      out.write(reinterpret_cast<const char*>(v.bytes.data()), static_cast<std::streamsize>(v.bytes.size()));
      return;
    }
    z_stream zs{};
    if (deflateInit2(&zs, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK) throw std::runtime_error("zlib: deflateInit failed");
    std::vector<unsigned char> buf(1 << 20);
    std::size_t done = 0;
    int rc;
    do {
      std::size_t take = std::min<std::size_t>(v.bytes.size() - done, 1u << 30);
      zs.next_in = const_cast<Bytef*>(v.bytes.data() + done);
      zs.avail_in = static_cast<uInt>(take);
      done += take;
      int flush = done == v.bytes.size() ? Z_FINISH : Z_NO_FLUSH;
      do {
        zs.next_out = buf.data();
        zs.avail_out = static_cast<uInt>(buf.size());
        rc = deflate(&zs, flush);
        out.write(reinterpret_cast<const char*>(buf.data()), static_cast<std::streamsize>(buf.size() - zs.avail_out));
      } while (zs.avail_out == 0);
    } while (done < v.bytes.size() || rc != Z_STREAM_END);
    deflateEnd(&zs);
  });
}

}  // namespace adaptiso
