// DICOM series reader (a folder of single-slice files, or one multi-frame file) through GDCM.
// Slices are grouped by SeriesInstanceUID (a folder with several series is refused), sorted by
// ImagePositionPatient projected on the slice normal, and the slice spacing is taken from those
// positions, not from SliceThickness. Rescale slope/intercept are applied per slice.
#include <gdcmDirectory.h>
#include <gdcmImageReader.h>
#include <gdcmScanner.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>

#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>
#include <sstream>

#include "adaptiso/volume_io.hpp"
#include "dicom_check.hpp"
#include "io_util.hpp"

namespace adaptiso {
namespace {

std::optional<ScalarType> gdcm_type(const gdcm::PixelFormat& pf) {
  switch (pf.GetScalarType()) {
    case gdcm::PixelFormat::UINT8:
      return ScalarType::u8;
    case gdcm::PixelFormat::INT8:
      return ScalarType::i8;
    case gdcm::PixelFormat::UINT12:
    case gdcm::PixelFormat::UINT16:
      return ScalarType::u16;
    case gdcm::PixelFormat::INT12:
    case gdcm::PixelFormat::INT16:
      return ScalarType::i16;
    case gdcm::PixelFormat::UINT32:
      return ScalarType::u32;
    case gdcm::PixelFormat::INT32:
      return ScalarType::i32;
    case gdcm::PixelFormat::FLOAT32:
      return ScalarType::f32;
    case gdcm::PixelFormat::FLOAT64:
      return ScalarType::f64;
    default:
      return std::nullopt;
  }
}

struct Slice {
  std::string file;
  double key = 0;
  std::array<double, 3> ipp{};
};

}  // namespace

Volume read_dicom_folder(const std::string& path) {
  // GDCM prints a line per tolerated quirk or error; adaptiso's one-line messages say what matters.
  gdcm::Trace::WarningOff();
  gdcm::Trace::DebugOff();
  gdcm::Trace::ErrorOff();
  namespace fs = std::filesystem;
  std::vector<std::string> candidates;
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    // error_code forms throughout: a symlink loop or an unreadable entry is skipped, not fatal.
    for (fs::directory_iterator it(path, ec), end; !ec && it != end; it.increment(ec))
      if (it->is_regular_file(ec) && !ec) candidates.push_back(it->path().string());
    if (ec) throw InputError(fmt::format("{}: cannot list the folder ({})", path, ec.message()));
    if (candidates.empty()) throw InputError(fmt::format("{}: folder is empty (expected the DICOM files of one series)", path));
  } else {
    candidates.push_back(path);
  }
  // Every file is walked before GDCM reads it (GDCM aborts on some corrupt files). A file that
  // says it is DICOM must be whole; one that does not and fails the walk is not DICOM (a README).
  std::vector<std::string> files;
  std::map<std::string, std::uint64_t> padded_from;
  for (const auto& f : candidates) {
    const bool claims = detail::has_dicom_magic(f);
    try {
      const detail::DicomSummary summary = detail::check_dicom_file(f);
      if (!summary.has_pixels) continue;
      files.push_back(f);
      if (summary.padded_from > 0) padded_from[f] = summary.padded_from;
    } catch (const InputError&) {
      if (claims || candidates.size() == 1) throw;
    }
  }
  if (files.empty()) throw InputError(fmt::format("{}: holds no DICOM images", path));
  std::sort(files.begin(), files.end());
  const gdcm::Tag t_series(0x0020, 0x000e), t_ipp(0x0020, 0x0032), t_iop(0x0020, 0x0037);
  gdcm::Scanner scanner;
  scanner.AddTag(t_series);
  scanner.AddTag(t_ipp);
  scanner.AddTag(t_iop);
  if (!scanner.Scan(files)) throw InputError(fmt::format("{}: cannot scan the DICOM files", path));
  std::map<std::string, std::vector<std::string>> series;
  for (const auto& f : files)
    if (scanner.IsKey(f.c_str())) {
      const char* uid = scanner.GetValue(f.c_str(), t_series);
      series[uid ? detail::trim(uid) : std::string{}].push_back(f);
    }
  if (series.empty()) throw InputError(fmt::format("{}: holds no DICOM files", path));
  if (series.size() > 1)
    throw InputError(fmt::format("{}: holds {} DICOM series (SeriesInstanceUID {} and {}); pass a folder with one series", path,
                                 series.size(), series.begin()->first, std::next(series.begin())->first));
  auto& sfiles = series.begin()->second;

  // Orientation from the first file; slice normal = row × column direction.
  std::array<double, 6> iop{1, 0, 0, 0, 1, 0};
  if (const char* s = scanner.GetValue(sfiles[0].c_str(), t_iop)) {
    std::string str(s);
    std::replace(str.begin(), str.end(), '\\', ' ');
    auto n = parse_number_list(str, -1, sfiles[0] + ": ImageOrientationPatient");
    if (n.size() == 6) std::copy(n.begin(), n.end(), iop.begin());
  }
  std::array<double, 3> nrm{iop[1] * iop[5] - iop[2] * iop[4], iop[2] * iop[3] - iop[0] * iop[5], iop[0] * iop[4] - iop[1] * iop[3]};
  std::vector<Slice> slices;
  for (const auto& f : sfiles) {
    Slice s{f, 0, {0, 0, 0}};
    if (const char* p = scanner.GetValue(f.c_str(), t_ipp)) {
      std::string str(p);
      std::replace(str.begin(), str.end(), '\\', ' ');
      auto n = parse_number_list(str, -1, f + ": ImagePositionPatient");
      if (n.size() == 3) s.ipp = {n[0], n[1], n[2]};
    }
    s.key = s.ipp[0] * nrm[0] + s.ipp[1] * nrm[1] + s.ipp[2] * nrm[2];
    slices.push_back(s);
  }
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.key < b.key; });
  for (std::size_t i = 1; i < slices.size(); ++i)
    if (std::abs(slices[i].key - slices[i - 1].key) < 1e-6)
      throw InputError(fmt::format("{}: {} and {} have the same slice position", path, slices[i - 1].file, slices[i].file));

  Volume v;
  std::vector<double> slope(slices.size(), 1.0), inter(slices.size(), 0.0);
  std::vector<unsigned char> buf;
  std::int64_t frames_per_file = 1;
  for (std::size_t si = 0; si < slices.size(); ++si) {
    gdcm::ImageReader reader;
    std::istringstream unpadded;  // outlives Read()
    if (auto p = padded_from.find(slices[si].file); p != padded_from.end()) {
      const std::vector<unsigned char> head = detail::read_bytes(slices[si].file, 0, p->second);
      unpadded.str(std::string(head.begin(), head.end()));
      reader.SetStream(unpadded);
    } else {
      reader.SetFileName(slices[si].file.c_str());
    }
    if (!reader.Read()) throw InputError(fmt::format("{}: cannot read the DICOM image", slices[si].file));
    const gdcm::Image& img = reader.GetImage();
    const gdcm::PixelFormat& pf = img.GetPixelFormat();
    if (pf.GetSamplesPerPixel() != 1)
      throw InputError(fmt::format("{}: {} samples per pixel; adaptiso reads grey-scale images", slices[si].file, pf.GetSamplesPerPixel()));
    auto type = gdcm_type(pf);
    if (!type) throw InputError(fmt::format("{}: pixel type {} is not supported", slices[si].file, pf.GetScalarTypeAsString()));
    std::int64_t cols = img.GetDimension(0), rows = img.GetDimension(1);
    std::int64_t frames = img.GetNumberOfDimensions() > 2 ? img.GetDimension(2) : 1;
    if (si == 0) {
      if (frames > 1 && slices.size() > 1) throw InputError(fmt::format("{}: mixes a multi-frame file with other slices", path));
      frames_per_file = frames;
      v.dims = {cols, rows, static_cast<std::int64_t>(slices.size()) * frames};
      v.type = *type;
      const std::size_t bytes = checked_volume_bytes(v.dims, scalar_size(v.type), path);
      detail::check_fits(path, bytes);
      v.bytes.resize(bytes);
      const double* sp = img.GetSpacing();
      v.spacing = {sp[0], sp[1], frames > 1 ? sp[2] : 1.0};
    } else if (cols != v.dims[0] || rows != v.dims[1] || *type != v.type) {
      throw InputError(fmt::format("{}: slice is {}x{} {}, the series' first is {}x{} {}", slices[si].file, cols, rows, scalar_name(*type),
                                   v.dims[0], v.dims[1], scalar_name(v.type)));
    }
    const std::size_t slice_bytes = static_cast<std::size_t>(cols * rows * frames) * scalar_size(v.type);
    if (img.GetBufferLength() != slice_bytes)
      throw InputError(fmt::format("{}: pixel data holds {} bytes, expected {}", slices[si].file, img.GetBufferLength(), slice_bytes));
    if (!img.GetBuffer(reinterpret_cast<char*>(v.bytes.data() + si * slice_bytes)))
      throw InputError(fmt::format("{}: cannot decode the pixel data", slices[si].file));
    slope[si] = img.GetSlope();
    inter[si] = img.GetIntercept();
  }
  // Geometry: x along the row direction, y along the column direction, z along the normal.
  for (int c = 0; c < 3; ++c) {
    v.direction[3 * c + 0] = iop[c];
    v.direction[3 * c + 1] = iop[3 + c];
    v.direction[3 * c + 2] = nrm[c];
  }
  v.origin = slices[0].ipp;
  if (slices.size() > 1) {
    const double mean = (slices.back().key - slices.front().key) / static_cast<double>(slices.size() - 1);
    for (std::size_t i = 1; i < slices.size(); ++i) {
      double gap = slices[i].key - slices[i - 1].key;
      if (std::abs(gap - mean) > 0.1 * mean)
        throw InputError(
            fmt::format("{}: slices are not evenly spaced ({:.6g} mm between {} and {}, mean {:.6g} mm); a slice may be missing", path, gap,
                        fs::path(slices[i - 1].file).filename().string(), fs::path(slices[i].file).filename().string(), mean));
    }
    v.spacing[2] = mean;
  }
  (void)frames_per_file;
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0) || !std::isfinite(v.spacing[a])) v.spacing[a] = 1.0;
  check_finite(v, path);

  bool rescale = false;
  for (std::size_t i = 0; i < slices.size(); ++i) rescale |= slope[i] != 1.0 || inter[i] != 0.0;
  if (rescale) {
    bool wide = v.type == ScalarType::u32 || v.type == ScalarType::i32 || v.type == ScalarType::f64;
    Volume out = make_volume(v.dims, wide ? ScalarType::f64 : ScalarType::f32);
    const std::int64_t per = v.dims[0] * v.dims[1] * frames_per_file;
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) {
      std::size_t s = static_cast<std::size_t>(i / per);
      out.set(i, v.at(i) * slope[s] + inter[s]);
    }
    v.bytes.swap(out.bytes);
    v.type = out.type;
  }
  return v;
}

}  // namespace adaptiso
