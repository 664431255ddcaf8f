// DICOM series reader (a folder of single-slice files, or one multi-frame file) through GDCM.
// Slices are grouped by SeriesInstanceUID (a folder with several series is refused), sorted by
// ImagePositionPatient projected on the slice normal, and the slice spacing is taken from those
// positions, not from SliceThickness. Rescale slope/intercept are applied per slice.
#include <gdcmDirectory.h>
#include <gdcmImageHelper.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmScanner.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>

#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>
#include <sstream>

#include "adaptiso/volume_io.hpp"
#include "dicom_check.hpp"
#include "dicom_series.hpp"
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

// The files of the one series at path, in order along the slice normal, and their orientation.
struct Scan {
  std::vector<Slice> slices;
  std::array<double, 6> iop{1, 0, 0, 0, 1, 0};
  std::array<double, 3> nrm{0, 0, 1};
};

Scan scan_series(const std::string& path) {
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
  for (const auto& f : candidates) {
    const bool claims = detail::has_dicom_magic(f);
    try {
      if (detail::check_dicom_file(f).has_pixels) files.push_back(f);
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
  Scan scan;
  auto& iop = scan.iop;
  if (const char* s = scanner.GetValue(sfiles[0].c_str(), t_iop)) {
    std::string str(s);
    std::replace(str.begin(), str.end(), '\\', ' ');
    auto n = parse_number_list(str, -1, sfiles[0] + ": ImageOrientationPatient");
    if (n.size() == 6) std::copy(n.begin(), n.end(), iop.begin());
  }
  scan.nrm = {iop[1] * iop[5] - iop[2] * iop[4], iop[2] * iop[3] - iop[0] * iop[5], iop[0] * iop[4] - iop[1] * iop[3]};
  for (const auto& f : sfiles) {
    Slice s{f, 0, {0, 0, 0}};
    if (const char* p = scanner.GetValue(f.c_str(), t_ipp)) {
      std::string str(p);
      std::replace(str.begin(), str.end(), '\\', ' ');
      auto n = parse_number_list(str, -1, f + ": ImagePositionPatient");
      if (n.size() == 3) s.ipp = {n[0], n[1], n[2]};
    }
    s.key = s.ipp[0] * scan.nrm[0] + s.ipp[1] * scan.nrm[1] + s.ipp[2] * scan.nrm[2];
    scan.slices.push_back(s);
  }
  auto& slices = scan.slices;
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.key < b.key; });
  for (std::size_t i = 1; i < slices.size(); ++i)
    if (std::abs(slices[i].key - slices[i - 1].key) < 1e-6)
      throw InputError(fmt::format("{}: {} and {} have the same slice position", path, slices[i - 1].file, slices[i].file));
  return scan;
}

// One file's image, walked again just before GDCM reads it (it may have changed since the series
// was scanned: GDCM aborts on some corrupt files), and only as far as its data set goes: zero
// padding after the pixel data would be parsed as empty elements, an exception each (2.1 s for
// 2.5 MB of zeros).
class SliceImage {
public:
  explicit SliceImage(const std::string& file) : file_(file) {
    // The walk reads the file; GDCM then reads it again from the page cache, or, when zero padding
    // follows the data set, from a copy of the data set alone (dropped once parsed).
    bool padded = false;
    {
      const std::vector<unsigned char> bytes = detail::read_bytes(file, 0, detail::file_size_or_throw(file));
      const detail::DicomSummary summary = detail::check_dicom_bytes(bytes, file);
      if (!summary.has_pixels) throw InputError(fmt::format("{}: holds no DICOM image", file));
      padded = summary.padded_from > 0;
      if (padded) data_.str(std::string(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(summary.padded_from)));
    }
    if (padded)
      reader_.SetStream(data_);
    else
      reader_.SetFileName(file.c_str());
    const bool read = reader_.Read();
    data_.str(std::string{});
    if (!read) throw InputError(fmt::format("{}: cannot read the DICOM image", file));
    const gdcm::PixelFormat& pf = image().GetPixelFormat();
    if (pf.GetSamplesPerPixel() != 1)
      throw InputError(fmt::format("{}: {} samples per pixel; adaptiso reads grey-scale images", file, pf.GetSamplesPerPixel()));
    const auto t = gdcm_type(pf);
    if (!t) throw InputError(fmt::format("{}: pixel type {} is not supported", file, pf.GetScalarTypeAsString()));
    type = *t;
    cols = image().GetDimension(0), rows = image().GetDimension(1);
    frames = image().GetNumberOfDimensions() > 2 ? image().GetDimension(2) : 1;
  }
  const gdcm::Image& image() const { return reader_.GetImage(); }

  // Refuses an image that is not `cols`×`rows` of `type`, as the series' first one is.
  void check_like(std::int64_t c, std::int64_t r, ScalarType t) const {
    if (cols != c || rows != r || type != t)
      throw InputError(
          fmt::format("{}: slice is {}x{} {}, the series' first is {}x{} {}", file_, cols, rows, scalar_name(type), c, r, scalar_name(t)));
  }
  void copy_pixels(unsigned char* out) const {
    const std::size_t bytes = static_cast<std::size_t>(cols * rows * frames) * scalar_size(type);
    if (image().GetBufferLength() != bytes)
      throw InputError(fmt::format("{}: pixel data holds {} bytes, expected {}", file_, image().GetBufferLength(), bytes));
    if (!image().GetBuffer(reinterpret_cast<char*>(out))) throw InputError(fmt::format("{}: cannot decode the pixel data", file_));
  }

  ScalarType type = ScalarType::u8;
  std::int64_t cols = 0, rows = 0, frames = 1;

private:
  std::string file_;
  std::istringstream data_;  // GDCM's input while it reads a padded file
  gdcm::ImageReader reader_;
};

// Geometry: x along the row direction, y along the column direction, z along the normal, the
// slice spacing from the slices' positions (`frame_spacing` for one file's frames).
void set_geometry(Volume& v, const Scan& scan, const double* pixel_spacing, double frame_spacing, const std::string& path) {
  namespace fs = std::filesystem;
  const auto& slices = scan.slices;
  v.spacing = {pixel_spacing[0], pixel_spacing[1], frame_spacing};
  for (int c = 0; c < 3; ++c) {
    v.direction[3 * c + 0] = scan.iop[c];
    v.direction[3 * c + 1] = scan.iop[3 + c];
    v.direction[3 * c + 2] = scan.nrm[c];
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
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0) || !std::isfinite(v.spacing[a])) v.spacing[a] = 1.0;
}

// Rescaled samples are float32, float64 for types float32 cannot hold exactly.
ScalarType rescaled_type(ScalarType stored) {
  return stored == ScalarType::u32 || stored == ScalarType::i32 || stored == ScalarType::f64 ? ScalarType::f64 : ScalarType::f32;
}

// `stored` (frames of `per` samples) as s × slope + inter of the frame's slice, into out (float32
// or float64, rescaled_type's; rounded as Volume::set rounds).
void rescale(const Volume& stored, const double* slope, const double* inter, std::int64_t per, ScalarType type, unsigned char* out) {
  auto to = [&]<class T>(T* o) {
    for (std::int64_t i = 0; i < stored.voxel_count(); ++i) {
      const std::size_t s = static_cast<std::size_t>(i / per);
      o[i] = static_cast<T>(stored.at(i) * slope[s] + inter[s]);
    }
  };
  if (type == ScalarType::f64) return to(reinterpret_cast<double*>(out));
  to(reinterpret_cast<float*>(out));
}

// A multi-frame file, read whole.
Volume read_frames(const Scan& scan, const SliceImage& img, const std::string& path) {
  Volume v;
  v.dims = {img.cols, img.rows, img.frames};
  v.type = img.type;
  const std::size_t bytes = checked_volume_bytes(v.dims, scalar_size(v.type), path);
  detail::check_fits(path, bytes);
  v.bytes.resize(bytes);
  img.copy_pixels(v.bytes.data());
  set_geometry(v, scan, img.image().GetSpacing(), img.image().GetSpacing()[2], path);
  check_finite(v, path);
  const double slope = img.image().GetSlope(), inter = img.image().GetIntercept();
  if (slope == 1.0 && inter == 0.0) return v;
  Volume out = make_volume(v.dims, rescaled_type(v.type));
  rescale(v, &slope, &inter, v.voxel_count(), out.type, out.bytes.data());
  out.spacing = v.spacing, out.origin = v.origin, out.direction = v.direction;
  return out;
}

std::optional<detail::DicomSeries> series_of(const Scan& scan, const SliceImage& first, const std::string& path) {
  if (first.frames > 1) {
    if (scan.slices.size() > 1) throw InputError(fmt::format("{}: mixes a multi-frame file with other slices", path));
    return std::nullopt;
  }
  detail::DicomSeries s;
  s.path = path;
  s.stored = first.type;
  s.header.dims = {first.cols, first.rows, static_cast<std::int64_t>(scan.slices.size())};
  s.header.type = first.type;
  set_geometry(s.header, scan, first.image().GetSpacing(), 1.0, path);
  // Each file's rescale as GDCM's ImageReader sets it (ImageHelper on the file's data set), from
  // its header alone: whether the series is rescaled decides its type before any slab is read.
  const gdcm::Tag pixel_data(0x7fe0, 0x0010);
  for (const Slice& slice : scan.slices) {
    detail::DicomSeries::File f{slice.file};
    gdcm::Reader header;
    header.SetFileName(slice.file.c_str());
    if (!header.ReadUpToTag(pixel_data, {})) throw InputError(fmt::format("{}: cannot read the DICOM header", slice.file));
    const std::vector<double> is = gdcm::ImageHelper::GetRescaleInterceptSlopeValue(header.GetFile());
    f.inter = is.at(0), f.slope = is.at(1);
    s.rescale |= f.slope != 1.0 || f.inter != 0.0;
    s.files.push_back(std::move(f));
  }
  if (s.rescale) s.header.type = rescaled_type(s.stored);
  return s;
}

}  // namespace

namespace detail {

std::optional<DicomSeries> open_dicom_series(const std::string& path) {
  const Scan scan = scan_series(path);
  const SliceImage first(scan.slices[0].file);
  return series_of(scan, first, path);
}

void read_dicom_slices(const DicomSeries& series, std::int64_t z0, std::int64_t z1, unsigned char* out) {
  const Dims& d = series.header.dims;
  if (z0 < 0 || z1 >= d[2] || z0 > z1)
    throw std::invalid_argument(fmt::format("read_dicom_slices: slices {}..{} are not inside the series' {}", z0, z1, d[2]));
  // Stored samples go straight to out, or, rescaled, to a slab of their own first.
  const std::size_t slice_bytes = static_cast<std::size_t>(d[0] * d[1]) * scalar_size(series.stored);
  const std::size_t n = static_cast<std::size_t>(z1 - z0 + 1);
  std::vector<unsigned char> staging(series.rescale ? n * slice_bytes : 0);
  unsigned char* to = series.rescale ? staging.data() : out;
  std::vector<double> slope, inter;
  for (std::int64_t z = z0; z <= z1; ++z) {
    const DicomSeries::File& f = series.files[static_cast<std::size_t>(z)];
    const SliceImage img(f.name);
    img.check_like(d[0], d[1], series.stored);
    if (img.frames != 1) throw InputError(fmt::format("{}: mixes a multi-frame file with other slices", series.path));
    img.copy_pixels(to + static_cast<std::size_t>(z - z0) * slice_bytes);
    // The header's rescale decided the series' type; GDCM gives the image the same (a guard).
    if (img.image().GetSlope() != f.slope || img.image().GetIntercept() != f.inter)
      throw InputError(fmt::format("{}: its image's rescale ({} × s + {}) is not its header's ({} × s + {})", f.name,
                                   img.image().GetSlope(), img.image().GetIntercept(), f.slope, f.inter));
    slope.push_back(f.slope), inter.push_back(f.inter);
  }
  Volume stored;
  stored.dims = {d[0], d[1], z1 - z0 + 1};
  stored.type = series.stored;
  stored.bytes = VoxelBuffer::view(to, n * slice_bytes, nullptr);
  check_finite(stored, series.path);
  if (series.rescale) rescale(stored, slope.data(), inter.data(), d[0] * d[1], series.header.type, out);
}

}  // namespace detail

Volume read_dicom_folder(const std::string& path) {
  const Scan scan = scan_series(path);
  const SliceImage first(scan.slices[0].file);
  const std::optional<detail::DicomSeries> series = series_of(scan, first, path);
  if (!series) return read_frames(scan, first, path);
  Volume v = series->header;
  const std::size_t bytes = checked_volume_bytes(v.dims, scalar_size(v.type), path);
  detail::check_fits(path, bytes);
  v.bytes.resize(bytes);
  detail::read_dicom_slices(*series, 0, v.dims[2] - 1, v.bytes.data());
  return v;
}

}  // namespace adaptiso
