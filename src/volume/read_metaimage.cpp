// MetaImage reader (.mha with LOCAL data, .mhd with a detached ElementDataFile, one file per slice
// via LIST or a format string, zlib CompressedData). Parsed directly: the format is a few
// "Key = Value" lines ending with ElementDataFile.
#include <fmt/format.h>
#include <cmath>
#include <filesystem>
#include <map>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"
#include "layout.hpp"

namespace adaptiso {
namespace {

std::optional<ScalarType> met_type(const std::string& t) {
  static const std::map<std::string, ScalarType> m = {
      {"MET_UCHAR", ScalarType::u8}, {"MET_CHAR", ScalarType::i8}, {"MET_USHORT", ScalarType::u16}, {"MET_SHORT", ScalarType::i16},
      {"MET_UINT", ScalarType::u32}, {"MET_INT", ScalarType::i32}, {"MET_FLOAT", ScalarType::f32},  {"MET_DOUBLE", ScalarType::f64}};
  auto it = m.find(t);
  if (it == m.end()) return std::nullopt;
  return it->second;
}

bool is_true(const std::string& s) {
  auto l = detail::lower(s);
  return l == "true" || l == "1" || l == "yes";
}

}  // namespace

namespace detail {

MetaImageLayout metaimage_layout(const std::string& path) {
  namespace fs = std::filesystem;
  const std::uint64_t size = detail::file_size_or_throw(path);
  // The header is text; read at most its first MiB to find ElementDataFile.
  auto head = detail::read_bytes(path, 0, std::min<std::uint64_t>(size, 1 << 20));
  std::map<std::string, std::string> kv;
  std::size_t pos = 0, data_offset = 0;
  std::vector<std::string> list_files;
  bool found_data_line = false;
  while (pos < head.size()) {
    std::size_t e = pos;
    while (e < head.size() && head[e] != '\n') ++e;
    std::string line(head.begin() + static_cast<long>(pos), head.begin() + static_cast<long>(e));
    pos = e + 1;
    auto eq = line.find('=');
    if (eq == std::string::npos) {
      if (detail::trim(line).empty()) continue;
      throw InputError(fmt::format("{}: not a MetaImage header (line '{}' has no '=')", path, detail::trim(line).substr(0, 60)));
    }
    std::string key = detail::trim(line.substr(0, eq)), val = detail::trim(line.substr(eq + 1));
    kv[key] = val;
    if (key == "ElementDataFile") {
      found_data_line = true;
      data_offset = std::min(pos, head.size());
      std::string lv = val;
      if (lv.rfind("LIST", 0) == 0) {
        // The remaining lines each name one data file.
        while (pos < head.size()) {
          std::size_t e2 = pos;
          while (e2 < head.size() && head[e2] != '\n') ++e2;
          std::string f = detail::trim(std::string(head.begin() + static_cast<long>(pos), head.begin() + static_cast<long>(e2)));
          pos = e2 + 1;
          if (!f.empty()) list_files.push_back(f);
        }
      }
      break;
    }
  }
  if (!found_data_line) throw InputError(fmt::format("{}: MetaImage header has no ElementDataFile line", path));
  auto get = [&](const char* k) -> std::string {
    auto it = kv.find(k);
    return it == kv.end() ? std::string{} : it->second;
  };
  const auto ndims =
      kv.count("NDims") ? detail::whole_number(parse_number_list(get("NDims"), 1, path + ": NDims")[0], 0, 100, path + ": NDims") : 3;
  if (ndims != 2 && ndims != 3) throw InputError(fmt::format("{}: NDims = {}; adaptiso reads 2D slices and 3D volumes", path, ndims));
  if (get("DimSize").empty()) throw InputError(fmt::format("{}: MetaImage header has no DimSize", path));
  auto ds = parse_number_list(get("DimSize"), ndims, path + ": DimSize");
  Dims dims{1, 1, 1};
  for (int a = 0; a < ndims; ++a) {
    if (!(ds[a] >= 1) || ds[a] != std::floor(ds[a]) || ds[a] > 1e12)
      throw InputError(fmt::format("{}: DimSize {} is not a positive whole number", path, ds[a]));
    dims[a] = static_cast<std::int64_t>(ds[a]);
  }
  auto type = met_type(get("ElementType"));
  if (!type) throw InputError(fmt::format("{}: ElementType '{}' is not supported", path, get("ElementType")));
  if (!get("ElementNumberOfChannels").empty() && get("ElementNumberOfChannels") != "1")
    throw InputError(fmt::format("{}: {} channels per voxel; adaptiso reads scalar volumes", path, get("ElementNumberOfChannels")));
  const std::size_t bytes = checked_volume_bytes(dims, scalar_size(*type), path);
  const bool msb = is_true(get("ElementByteOrderMSB")) || is_true(get("BinaryDataByteOrderMSB"));
  const bool compressed = is_true(get("CompressedData"));
  const std::int64_t header_size =
      get("HeaderSize").empty() ? 0
                                : detail::whole_number(parse_number_list(get("HeaderSize"), 1, path)[0], -1, 1e18, path + ": HeaderSize");

  // Data sources: LOCAL, one file, a LIST, or "format min max step".
  fs::path dir = fs::path(path).parent_path();
  auto resolve = [&](const std::string& n) { return (fs::path(n).is_absolute() ? fs::path(n) : dir / n).string(); };
  std::string edf = get("ElementDataFile");
  MetaImageLayout l;
  bool local = edf == "LOCAL" || edf == "Local" || edf == "local";
  if (local) {
    l.files.push_back(path);
  } else if (edf.rfind("LIST", 0) == 0) {
    for (auto& f : list_files) l.files.push_back(resolve(f));
  } else if (edf.find('%') != std::string::npos) {
    for (const auto& f : detail::numbered_files(edf, dims[ndims - 1], path + ": ElementDataFile")) l.files.push_back(resolve(f));
  } else {
    l.files.push_back(resolve(edf));
  }
  if (l.files.empty()) throw InputError(fmt::format("{}: ElementDataFile names no files", path));
  if (bytes % l.files.size() != 0) throw InputError(fmt::format("{}: {} data files do not divide the volume evenly", path, l.files.size()));
  const std::size_t per_file = bytes / l.files.size();

  // Check the sizes on disk before anything is allocated.
  std::uint64_t avail = 0;
  for (const auto& f : l.files) {
    std::uint64_t s = detail::file_size_or_throw(f);
    if (f == path) s = s > data_offset ? s - data_offset : 0;
    avail += compressed ? detail::max_inflated_size(s) : s;
  }
  if (bytes > avail)
    throw InputError(fmt::format("{}: header says {}x{}x{} {} ({} bytes) but the data holds only {} bytes", path, dims[0], dims[1], dims[2],
                                 scalar_name(*type), bytes, avail));
  for (const auto& f : l.files) {
    const std::uint64_t fsize = detail::file_size_or_throw(f);
    std::uint64_t start = f == path ? data_offset : 0;
    if (compressed) {
      std::uint64_t csize = fsize - std::min(fsize, start);
      if (!get("CompressedDataSize").empty() && l.files.size() == 1) {
        auto c = parse_number_list(get("CompressedDataSize"), 1, path)[0];
        if (c > 0 && c <= static_cast<double>(csize)) csize = static_cast<std::uint64_t>(c);
      }
      l.starts.push_back(start), l.stored.push_back(csize);
    } else {
      if (header_size > 0)
        start += static_cast<std::uint64_t>(header_size);
      else if (header_size == -1)
        start = fsize >= per_file ? fsize - per_file : 0;
      l.starts.push_back(start), l.stored.push_back(per_file);
    }
  }
  l.bytes = bytes, l.compressed = compressed, l.swap = msb == detail::host_is_little_endian();

  Volume& v = l.header;
  v.dims = dims;
  v.type = *type;
  std::string sp = get("ElementSpacing").empty() ? get("ElementSize") : get("ElementSpacing");
  if (!sp.empty()) {
    auto s = parse_number_list(sp, -1, path + ": ElementSpacing");
    for (int a = 0; a < std::min<int>(3, static_cast<int>(s.size())); ++a) v.spacing[a] = std::abs(s[a]);
  }
  for (const char* k : {"Offset", "Position", "Origin"})
    if (!get(k).empty()) {
      auto o = parse_number_list(get(k), -1, path + ": " + k);
      for (int a = 0; a < std::min<int>(3, static_cast<int>(o.size())); ++a) v.origin[a] = o[a];
      break;
    }
  for (const char* k : {"TransformMatrix", "Rotation", "Orientation"})
    if (!get(k).empty()) {
      auto m = parse_number_list(get(k), -1, path + ": " + k);
      if (ndims == 3 && m.size() == 9) {
        // MetaImage stores the matrix row by row with row a = direction of index axis a.
        for (int a = 0; a < 3; ++a)
          for (int c = 0; c < 3; ++c) v.direction[3 * c + a] = m[3 * a + c];
      }
      break;
    }
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0) || !std::isfinite(v.spacing[a]))
      throw InputError(fmt::format("{}: ElementSpacing along axis {} is not a positive number", path, a));
  return l;
}

}  // namespace detail

Volume read_metaimage(const std::string& path) {
  detail::MetaImageLayout l = detail::metaimage_layout(path);
  Volume v = std::move(l.header);
  detail::check_fits(path, l.bytes);
  v.bytes.resize(l.bytes);
  const std::size_t per_file = l.bytes / l.files.size();
  for (std::size_t fi = 0; fi < l.files.size(); ++fi) {
    unsigned char* dst = v.bytes.data() + fi * per_file;
    auto stored = detail::read_bytes(l.files[fi], l.starts[fi], l.stored[fi]);  // throws when the file is truncated
    if (l.compressed)
      detail::inflate_exact(stored.data(), stored.size(), dst, per_file, l.files[fi]);
    else
      std::copy(stored.begin(), stored.end(), dst);
  }
  if (l.swap) detail::byteswap(v.bytes.data(), scalar_size(v.type), static_cast<std::size_t>(v.voxel_count()));
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
