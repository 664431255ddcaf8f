// Format dispatch by path (extension, folder, then magic bytes) and the NRRD writer.
#include <zlib.h>

#include <fmt/format.h>
#include <filesystem>
#include <sstream>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

namespace adaptiso {

namespace {

Volume read_any(const std::string& path, const ReadOptions& options) {
  namespace fs = std::filesystem;
  if (options.raw) return read_raw(path, *options.raw);
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(fmt::format("{}: no such file or folder", path));
  if (fs::is_directory(path, ec)) return read_dicom_folder(path);
  const std::string l = detail::lower(path);
  auto ends = [&](std::string_view s) { return l.ends_with(s); };
  if (ends(".tar.gz") || ends(".tgz") || ends(".tar") || ends(".zip"))
    throw InputError(fmt::format("{}: is an archive; unpack it first (e.g. tar xzf {}) and pass the folder of DICOM files", path,
                                 fs::path(path).filename().string()));
  if (ends(".nrrd") || ends(".nhdr")) return read_nrrd(path);
  if (ends(".nii") || ends(".nii.gz") || ends(".hdr")) return read_nifti(path);
  if (ends(".mha") || ends(".mhd")) return read_metaimage(path);
  if (ends(".vti")) return read_vti(path);
  if (ends(".vtk")) return read_legacy_vtk(path);
  if (ends(".dcm")) return read_dicom_folder(path);
  if (ends(".raw") || ends(".img") || ends(".bin"))
    throw OptionError(
        "dims",
        fmt::format("{} holds raw samples: give its dimensions and element type (and byte order, spacing, header size as needed)", path));
  // Unknown extension: look at the first bytes.
  std::uint64_t size = detail::file_size_or_throw(path);
  auto head = detail::read_bytes(path, 0, std::min<std::uint64_t>(size, 352));
  std::string h(head.begin(), head.end());
  if (h.starts_with("NRRD000")) return read_nrrd(path);
  if (h.starts_with("# vtk DataFile")) return read_legacy_vtk(path);
  if (h.find("<VTKFile") != std::string::npos) return read_vti(path);
  if (h.size() >= 348 && (h.compare(344, 4, std::string("n+1\0", 4)) == 0)) return read_nifti(path);
  if (h.size() >= 8 && (h.compare(4, 4, std::string("n+2\0", 4)) == 0)) return read_nifti(path);
  if (h.size() >= 132 && h.compare(128, 4, "DICM") == 0) return read_dicom_folder(path);
  if (h.find("ElementDataFile") != std::string::npos || h.starts_with("ObjectType") || h.starts_with("NDims")) return read_metaimage(path);
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
