// NRRD reader (.nrrd attached, .nhdr detached; raw/gzip/…; one file per slice) through teem.
// The header is read first with skipData so the volume's size can be checked against the bytes
// on disk before teem allocates anything.
#include <teem/nrrd.h>

#include <fmt/format.h>
#include <cmath>
#include <filesystem>
#include <mutex>

#include "adaptiso/volume_io.hpp"
#include "io_util.hpp"

namespace adaptiso {
namespace {

std::mutex teem_mutex;  // biff's error accumulation is global state

std::string biff_message() {
  char* err = biffGetDone(NRRD);
  std::string all = err ? err : "unknown error";
  free(err);
  // biff stacks one line per call level, outermost first; the innermost says what is wrong.
  std::string best;
  std::size_t pos = 0;
  while (pos < all.size()) {
    auto e = all.find('\n', pos);
    std::string line = detail::trim(all.substr(pos, e == std::string::npos ? std::string::npos : e - pos));
    if (!line.empty()) best = line;
    if (e == std::string::npos) break;
    pos = e + 1;
  }
  // Strip "[nrrd] _nrrdFunction: " prefixes.
  if (auto b = best.find("] "); best.starts_with("[") && b != std::string::npos) best = best.substr(b + 2);
  if (auto c = best.find(": "); c != std::string::npos && best.substr(0, c).find(' ') == std::string::npos) best = best.substr(c + 2);
  return best;
}

struct NrrdHolder {
  Nrrd* n = nrrdNew();
  NrrdIoState* nio = nrrdIoStateNew();
  ~NrrdHolder() {
    nrrdNuke(n);
    nrrdIoStateNix(nio);
  }
};

std::optional<ScalarType> from_teem(int t) {
  switch (t) {
    case nrrdTypeChar:
      return ScalarType::i8;
    case nrrdTypeUChar:
      return ScalarType::u8;
    case nrrdTypeShort:
      return ScalarType::i16;
    case nrrdTypeUShort:
      return ScalarType::u16;
    case nrrdTypeInt:
      return ScalarType::i32;
    case nrrdTypeUInt:
      return ScalarType::u32;
    case nrrdTypeFloat:
      return ScalarType::f32;
    case nrrdTypeDouble:
      return ScalarType::f64;
    default:
      return std::nullopt;
  }
}

// Which files hold the data, resolved against the header's folder.
std::vector<std::string> data_files(const std::string& header, const NrrdIoState* nio) {
  namespace fs = std::filesystem;
  fs::path dir = fs::path(header).parent_path();
  auto resolve = [&](const std::string& name) {
    fs::path p(name);
    return (p.is_absolute() ? p : dir / p).string();
  };
  std::vector<std::string> files;
  if (nio->dataFNFormat) {
    if (nio->dataFNStep == 0) throw InputError(fmt::format("{}: data file format has step 0", header));
    long count = (static_cast<long>(nio->dataFNMax) - nio->dataFNMin) / nio->dataFNStep + 1;
    if (count <= 0 || count > 1000000) throw InputError(fmt::format("{}: data file range is invalid", header));
    for (int i = nio->dataFNMin;; i += nio->dataFNStep) {
      if (nio->dataFNStep > 0 ? i > nio->dataFNMax : i < nio->dataFNMax) break;
      char buf[4096];
      std::snprintf(buf, sizeof buf, nio->dataFNFormat, i);
      files.push_back(resolve(buf));
    }
  } else if (nio->dataFNArr && nio->dataFNArr->len > 0) {
    for (unsigned i = 0; i < nio->dataFNArr->len; ++i) files.push_back(resolve(nio->dataFN[i]));
  } else {
    files.push_back(header);
  }
  return files;
}

}  // namespace

Volume read_nrrd(const std::string& path) {
  detail::file_size_or_throw(path);
  std::lock_guard lock(teem_mutex);
  nrrdStateVerboseIO = 0;
  std::uint64_t expected = 0, on_disk = 0;
  Dims dims{1, 1, 1};
  ScalarType type{};
  {
    NrrdHolder h;
    h.nio->skipData = AIR_TRUE;
    if (nrrdLoad(h.n, path.c_str(), h.nio)) throw InputError(fmt::format("{}: cannot read NRRD header: {}", path, biff_message()));
    auto t = from_teem(h.n->type);
    if (!t)
      throw InputError(fmt::format("{}: NRRD type '{}' is not supported (use 8/16/32-bit integers, float or double)", path,
                                   airEnumStr(nrrdType, h.n->type)));
    type = *t;
    unsigned dim = h.n->dim;
    unsigned first = 0;
    if (dim == 4 && h.n->axis[0].size == 1)
      first = 1;  // a 1-component axis in front
    else if (dim != 2 && dim != 3)
      throw InputError(fmt::format("{}: NRRD has {} axes; adaptiso reads 2D slices and 3D scalar volumes", path, dim));
    for (unsigned a = first; a < dim; ++a) dims[a - first] = static_cast<std::int64_t>(h.n->axis[a].size);
    expected = checked_volume_bytes(dims, scalar_size(type), path);
    for (const auto& f : data_files(path, h.nio)) {
      std::error_code ec;
      auto s = std::filesystem::file_size(f, ec);
      if (ec) throw InputError(fmt::format("{}: data file {} is missing or unreadable", path, f));
      on_disk += s;
    }
    const NrrdEncoding* enc = h.nio->encoding;
    std::uint64_t bound = on_disk;
    if (enc->isCompression)
      bound = enc == nrrdEncodingGzip ? detail::max_inflated_size(on_disk) : on_disk * 50000;
    else if (enc == nrrdEncodingAscii)
      bound = on_disk * scalar_size(type);
    if (expected > bound)
      throw InputError(fmt::format("{}: header says {}x{}x{} {} ({} bytes) but the data file(s) hold only {} bytes{}", path, dims[0],
                                   dims[1], dims[2], scalar_name(type), expected, on_disk, enc->isCompression ? " compressed" : ""));
  }
  NrrdHolder h;
  if (nrrdLoad(h.n, path.c_str(), h.nio)) throw InputError(fmt::format("{}: cannot read NRRD data: {}", path, biff_message()));
  if (nrrdElementNumber(h.n) * nrrdElementSize(h.n) != expected) throw InputError(fmt::format("{}: NRRD changed while reading", path));
  Volume v;
  v.dims = dims;
  v.type = type;
  const unsigned first = h.n->dim - (h.n->dim == 2 ? 2 : 3);
  const auto* src = static_cast<const unsigned char*>(h.n->data);
  v.bytes.assign(src, src + expected);

  // Geometry: "space directions" (world vectors) when present, else per-axis "spacings".
  const unsigned nax = h.n->dim - first;
  for (unsigned a = 0; a < nax; ++a) {
    const NrrdAxisInfo& ax = h.n->axis[first + a];
    double len = 0;
    bool have_dir = h.n->spaceDim >= 3;
    for (unsigned c = 0; have_dir && c < 3; ++c) {
      if (!std::isfinite(ax.spaceDirection[c]))
        have_dir = false;
      else
        len += ax.spaceDirection[c] * ax.spaceDirection[c];
    }
    len = std::sqrt(len);
    if (have_dir && len > 0) {
      v.spacing[a] = len;
      for (unsigned c = 0; c < 3; ++c) v.direction[3 * c + a] = ax.spaceDirection[c] / len;
    } else if (std::isfinite(ax.spacing) && ax.spacing != 0) {
      v.spacing[a] = std::abs(ax.spacing);
      if (ax.spacing < 0) v.direction[3 * a + a] = -1;
    }
  }
  if (h.n->spaceDim >= 3)
    for (unsigned c = 0; c < 3; ++c)
      if (std::isfinite(h.n->spaceOrigin[c])) v.origin[c] = h.n->spaceOrigin[c];
  for (int a = 0; a < 3; ++a)
    if (!(v.spacing[a] > 0) || !std::isfinite(v.spacing[a]))
      throw InputError(fmt::format("{}: spacing along axis {} is not a positive number", path, a));
  check_finite(v, path);
  return v;
}

}  // namespace adaptiso
