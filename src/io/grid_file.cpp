// The .adg grid file (see grid_file.hpp) and the .vtu export.
#include "adaptiso/grid_file.hpp"

#include <libdeflate.h>

#include <fmt/format.h>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "adaptiso/atomic_file.hpp"
#include "util/big_array.hpp"
#include "volume/io_util.hpp"

namespace adaptiso {
namespace {

constexpr char kMagic[16] = {'A', 'D', 'A', 'P', 'T', 'I', 'S', 'O', '-', 'G', 'R', 'I', 'D', 0, 0, 0};
// Version 4: the index lists' equal keys may come in any order (earlier ones: by tetrahedron id),
// so a build that reads 3 does not call a version 4 file corrupt. The layout is version 3's.
constexpr std::uint32_t kVersion = 4;
constexpr std::uint64_t kHeaderV1 = 48, kHeader = 64;
constexpr std::uint32_t kHasIndex = 1, kHasHierarchy = 2, kHasDisplacement = 4;
constexpr std::uint64_t kHierarchyHeader = 40;  // i32 root size, u8 thresholds ×2, u16 reserved, f64 ×4
constexpr std::uint64_t kNodeBytes = 24;        // f64 split, u64 begin, u64 end

nlohmann::json source_json(const GridSource& s) {
  return {{"dims", s.dims}, {"spacing", s.spacing}, {"origin", s.origin}, {"direction", s.direction}, {"type", s.type},
          {"min", s.min},   {"max", s.max},         {"method", s.method}, {"max_error", s.max_error}, {"threshold", s.threshold},
          {"file", s.file}};
}

class CrcWriter {
public:
  explicit CrcWriter(std::ostream& o) : out_(o) {}
  void write(const void* p, std::size_t n) {
    crc_ = libdeflate_crc32(crc_, p, n);
    out_.write(static_cast<const char*>(p), static_cast<std::streamsize>(n));
  }
  template <class T>
  void put(const T& x) {
    write(&x, sizeof x);
  }
  std::uint32_t crc() const { return crc_; }

private:
  std::ostream& out_;
  std::uint32_t crc_ = 0;
};

// A hierarchy read from a file: scales and thresholds that codes can have, a root cube that is the
// volume's, spans that are ordered (or empty).
void validate_hierarchy(const BisectionHierarchy& h, const TetGrid& grid, const std::string& path) {
  auto fail = [&](const char* why) { throw InputError(fmt::format("{}: grid hierarchy is corrupt ({})", path, why)); };
  std::int64_t extent = 1;
  for (int a = 0; a < 3; ++a) extent = std::max<std::int64_t>(extent, grid.source.dims[a] - 1);
  if (static_cast<std::uint64_t>(h.root_size) != std::bit_ceil(static_cast<std::uint64_t>(extent))) fail("root cube");
  for (const ErrorCodes* c : {&h.codes, &h.displacement_codes})
    if (!(c->scale > 0) || !std::isfinite(c->scale) || !(c->zero >= 0) || !std::isfinite(c->zero)) fail("code scale");
  if (h.error_threshold > 254 || h.displacement_threshold > 254) fail("threshold");
  for (const auto& s : h.value_span)
    if (std::isnan(s[0]) || std::isnan(s[1]) || (s[0] > s[1] && !(s[0] == std::numeric_limits<float>::infinity() && s[1] == -s[0])))
      fail("value span");
}

}  // namespace

void save_grid(const PreparedGrid& p, const std::string& path, bool with_index) {
  const TetGrid& grid = p.grid;
  const IntervalTree* index = with_index ? &p.index : nullptr;
  // Timings and memory peaks vary from run to run: the file keeps the rest, so the same input and
  // options give the same bytes.
  nlohmann::json stats = nlohmann::json::parse(to_json(p.stats));
  stats.erase("seconds");
  stats.erase("peak_bytes");
  const nlohmann::json meta = {{"source", source_json(grid.source)}, {"prepare", stats}};
  const std::string m = meta.dump();
  write_file_atomically(path, [&](std::ostream& out) {
    CrcWriter w(out);
    w.write(kMagic, 16);
    const BisectionHierarchy* h = p.hierarchy ? &*p.hierarchy : nullptr;
    const bool moves = h && !h->displacement_code.empty();
    w.put(kVersion);
    w.put((index ? kHasIndex : 0) | (h ? kHasHierarchy : 0) | (moves ? kHasDisplacement : 0));
    w.put(static_cast<std::uint64_t>(m.size()));
    w.put(static_cast<std::uint64_t>(grid.vertex_count()));
    w.put(static_cast<std::uint64_t>(grid.tet_count()));
    w.put(static_cast<std::uint64_t>(index ? index->entries() : 0));
    w.put(index ? index->depth : std::uint32_t{0});
    w.put(std::uint32_t{0});
    w.write(m.data(), m.size());
    w.write(grid.ijk.data(), grid.ijk.size() * sizeof grid.ijk[0]);
    w.write(grid.values.data(), grid.values.size() * sizeof(double));
    w.write(grid.gradients.data(), grid.gradients.size() * sizeof grid.gradients[0]);
    w.write(grid.tets.data(), grid.tets.size() * sizeof grid.tets[0]);
    if (index) {
      for (const auto& n : index->nodes) {
        w.put(n.split);
        w.put(n.begin);
        w.put(n.end);
      }
      w.write(index->by_min.data(), index->by_min.size() * 4);
      w.write(index->by_max.data(), index->by_max.size() * 4);
    }
    if (h) {
      w.put(h->root_size);
      w.put(h->error_threshold);
      w.put(h->displacement_threshold);
      w.put(std::uint16_t{0});
      w.put(h->codes.scale);
      w.put(h->codes.zero);
      w.put(h->displacement_codes.scale);
      w.put(h->displacement_codes.zero);
      w.write(h->error_code.data(), h->error_code.size());
      if (moves) w.write(h->displacement_code.data(), h->displacement_code.size());
      w.write(h->value_span.data(), h->value_span.size() * 8);
    }
    std::uint32_t c = w.crc();
    out.write(reinterpret_cast<const char*>(&c), 4);
  });
}

PreparedGrid load_grid(const std::string& path) {
  detail::file_size_or_throw(path);  // a FIFO or device would block or never end
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw InputError(fmt::format("{}: cannot open grid file", path));
  const std::uint64_t size = static_cast<std::uint64_t>(in.tellg());
  in.seekg(0);
  if (size < kHeaderV1 + 4) throw InputError(fmt::format("{}: not an adaptiso grid file (too short)", path));
  unsigned char h[kHeader] = {};
  in.read(reinterpret_cast<char*>(h), kHeaderV1);
  if (std::memcmp(h, kMagic, 16) != 0) throw InputError(fmt::format("{}: not an adaptiso grid file (bad magic)", path));
  std::uint32_t version, flags, depth = 0;
  std::uint64_t M, N, T, E = 0;
  std::memcpy(&version, h + 16, 4);
  std::memcpy(&flags, h + 20, 4);
  std::memcpy(&M, h + 24, 8);
  std::memcpy(&N, h + 32, 8);
  std::memcpy(&T, h + 40, 8);
  if (version < 1 || version > kVersion)
    throw InputError(fmt::format("{}: grid file version {} is not supported (this build reads 1 to {})", path, version, kVersion));
  std::uint64_t header = kHeaderV1;
  if (version >= 2) {
    header = kHeader;
    if (size < kHeader + 4) throw InputError(fmt::format("{}: grid file is truncated", path));
    in.read(reinterpret_cast<char*>(h + kHeaderV1), kHeader - kHeaderV1);
    std::memcpy(&E, h + 48, 8);
    std::memcpy(&depth, h + 56, 4);
  }
  const bool has_index = version >= 2 && (flags & kHasIndex);
  const bool has_hierarchy = version >= 3 && (flags & kHasHierarchy), has_moves = version >= 3 && (flags & kHasDisplacement);
  const std::uint32_t known = version >= 3 ? (kHasIndex | kHasHierarchy | kHasDisplacement) : kHasIndex;
  if ((version == 1 && flags != 0) || (version >= 2 && (flags & ~known)) || depth > 30 || (!has_index && (E || depth)) ||
      (has_moves && !has_hierarchy))
    throw InputError(fmt::format("{}: grid file is corrupt (bad header flags)", path));
  const std::uint64_t nodes = has_index ? (std::uint64_t{2} << depth) - 1 : 0;
  // The size the counts imply must be the file's size; checked without overflow before allocating.
  const std::uint64_t per_vertex = 12 + 8 + 12 + (has_hierarchy ? 1 + 8 : 0) + (has_moves ? 1 : 0), per_tet = 16;
  if (M > size || N > size / per_vertex || T > size / per_tet || E > T || nodes > size / kNodeBytes ||
      header + 4 + M + N * per_vertex + T * per_tet + nodes * kNodeBytes + E * 8 + (has_hierarchy ? kHierarchyHeader : 0) != size)
    throw InputError(fmt::format("{}: grid file is truncated or corrupt (size {} does not match its header)", path, size));
  if (N > std::numeric_limits<std::uint32_t>::max() || T > std::numeric_limits<std::uint32_t>::max())
    throw InputError(fmt::format("{}: too many vertices or tetrahedra", path));
  std::uint32_t crc = libdeflate_crc32(0, h, header);
  auto read = [&](void* p, std::size_t n) {
    in.read(static_cast<char*>(p), static_cast<std::streamsize>(n));
    if (static_cast<std::size_t>(in.gcount()) != n) throw InputError(fmt::format("{}: grid file is truncated", path));
    crc = libdeflate_crc32(crc, p, n);
  };
  std::string meta(M, '\0');
  read(meta.data(), M);
  PreparedGrid p;
  TetGrid& grid = p.grid;
  detail::resize_big(grid.ijk, N);
  detail::resize_big(grid.values, N);
  detail::resize_big(grid.gradients, N);
  detail::resize_big(grid.tets, T);
  read(grid.ijk.data(), N * 12);
  read(grid.values.data(), N * 8);
  read(grid.gradients.data(), N * 12);
  read(grid.tets.data(), T * 16);
  IntervalTree tree;
  if (has_index) {
    tree.depth = depth;
    tree.nodes.resize(nodes);
    std::vector<unsigned char> raw(nodes * kNodeBytes);
    read(raw.data(), raw.size());
    for (std::uint64_t i = 0; i < nodes; ++i) {
      std::memcpy(&tree.nodes[i].split, &raw[i * kNodeBytes], 8);
      std::memcpy(&tree.nodes[i].begin, &raw[i * kNodeBytes + 8], 8);
      std::memcpy(&tree.nodes[i].end, &raw[i * kNodeBytes + 16], 8);
    }
    detail::resize_big(tree.by_min, E);
    detail::resize_big(tree.by_max, E);
    read(tree.by_min.data(), E * 4);
    read(tree.by_max.data(), E * 4);
  }
  if (has_hierarchy) {
    BisectionHierarchy& hh = p.hierarchy.emplace();
    std::uint16_t reserved = 0;
    read(&hh.root_size, 4);
    read(&hh.error_threshold, 1);
    read(&hh.displacement_threshold, 1);
    read(&reserved, 2);
    read(&hh.codes.scale, 8);
    read(&hh.codes.zero, 8);
    read(&hh.displacement_codes.scale, 8);
    read(&hh.displacement_codes.zero, 8);
    detail::resize_big(hh.error_code, N);
    read(hh.error_code.data(), N);
    if (has_moves) {
      detail::resize_big(hh.displacement_code, N);
      read(hh.displacement_code.data(), N);
    }
    detail::resize_big(hh.value_span, N);
    read(hh.value_span.data(), N * 8);
  }
  std::uint32_t stored;
  in.read(reinterpret_cast<char*>(&stored), 4);
  if (static_cast<std::uint32_t>(crc) != stored) throw InputError(fmt::format("{}: grid file is corrupt (checksum mismatch)", path));
  auto j = nlohmann::json::parse(meta, nullptr, false);
  if (j.is_discarded() || !j.contains("source")) throw InputError(fmt::format("{}: grid metadata is not valid JSON", path));
  try {
    const auto& s = j["source"];
    grid.source.dims = s.at("dims").get<Dims>();
    grid.source.spacing = s.at("spacing").get<Vec3>();
    grid.source.origin = s.at("origin").get<Vec3>();
    grid.source.direction = s.at("direction").get<std::array<double, 9>>();
    grid.source.type = s.at("type").get<std::string>();
    grid.source.min = s.at("min").get<double>();
    grid.source.max = s.at("max").get<double>();
    grid.source.method = s.at("method").get<std::string>();
    // No error criterion (+∞) is written as null, JSON having no infinity.
    grid.source.max_error = s.at("max_error").is_null() ? std::numeric_limits<double>::infinity() : s.at("max_error").get<double>();
    grid.source.threshold = s.at("threshold").get<double>();
    grid.source.file = s.at("file").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    throw InputError(fmt::format("{}: grid metadata is incomplete ({})", path, e.what()));
  }
  for (int a = 0; a < 3; ++a)
    if (grid.source.dims[a] < 1 || !(grid.source.spacing[a] > 0))
      throw InputError(fmt::format("{}: grid metadata has invalid dims or spacing", path));
  for (const auto& t : grid.tets)
    for (auto v : t)
      if (v >= N) throw InputError(fmt::format("{}: a tetrahedron references vertex {} of {}", path, v, N));
  for (std::size_t i = 0; i < N; ++i) {
    if (!std::isfinite(grid.values[i])) throw InputError(fmt::format("{}: vertex {} has a non-finite value", path, i));
    for (int a = 0; a < 3; ++a)
      if (grid.ijk[i][a] >= static_cast<std::uint64_t>(grid.source.dims[a]))
        throw InputError(fmt::format("{}: vertex {} lies outside the volume", path, i));
  }
  if (p.hierarchy) validate_hierarchy(*p.hierarchy, grid, path);
  if (has_index) {
    validate_interval_tree(tree, grid, path);
    finish_interval_tree(tree, grid);
    p.index = std::move(tree);
  } else {
    p.index = build_interval_tree(grid);  // an older file: build the index now
  }
  if (j.contains("prepare") && j["prepare"].is_object()) p.stats = prepare_stats_from_json(j["prepare"].dump());
  return p;
}

double grid_bytes_per_vertex(const TetGrid& grid, const IntervalTree& index) {
  const double bytes = grid.vertex_count() * (12.0 + 8 + 12) + grid.tet_count() * 16.0 + index.entries() * 8.0 + index.nodes.size() * 24.0;
  return grid.vertex_count() ? bytes / static_cast<double>(grid.vertex_count()) : 0;
}

void write_vtu(const TetGrid& grid, const std::string& path) {
  const std::uint64_t n = grid.vertex_count(), t = grid.tet_count();
  std::vector<float> pts(n * 3), grad(n * 3);
  for (std::uint64_t v = 0; v < n; ++v) {
    Vec3 w = grid.world_position(static_cast<std::uint32_t>(v));
    const auto& d = grid.source.direction;
    const auto& gr = grid.gradients[v];
    for (int a = 0; a < 3; ++a) {
      pts[3 * v + a] = static_cast<float>(w[a]);
      grad[3 * v + a] = static_cast<float>(d[3 * a] * gr[0] + d[3 * a + 1] * gr[1] + d[3 * a + 2] * gr[2]);
    }
  }
  std::vector<std::uint64_t> offsets(t);
  for (std::uint64_t i = 0; i < t; ++i) offsets[i] = 4 * (i + 1);
  std::vector<std::uint8_t> types(t, 10);  // VTK_TETRA
  struct Arr {
    const void* p;
    std::uint64_t bytes;
  };
  std::vector<Arr> arrays = {{pts.data(), pts.size() * 4}, {grid.tets.data(), t * 16},    {offsets.data(), t * 8}, {types.data(), t},
                             {grid.values.data(), n * 8},  {grad.data(), grad.size() * 4}};
  std::vector<std::uint64_t> off;
  std::uint64_t o = 0;
  for (const auto& a : arrays) {
    off.push_back(o);
    o += 8 + a.bytes;
  }
  write_file_atomically(path, [&](std::ostream& out) {
    out << "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
           "header_type=\"UInt64\">\n"
        << fmt::format("<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n", n, t)
        << fmt::format("<Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"appended\" offset=\"{}\"/></Points>\n",
                       off[0])
        << "<Cells>\n"
        << fmt::format("<DataArray type=\"UInt32\" Name=\"connectivity\" format=\"appended\" offset=\"{}\"/>\n", off[1])
        << fmt::format("<DataArray type=\"UInt64\" Name=\"offsets\" format=\"appended\" offset=\"{}\"/>\n", off[2])
        << fmt::format("<DataArray type=\"UInt8\" Name=\"types\" format=\"appended\" offset=\"{}\"/>\n", off[3]) << "</Cells>\n"
        << "<PointData Scalars=\"value\" Vectors=\"gradient\">\n"
        << fmt::format("<DataArray type=\"Float64\" Name=\"value\" format=\"appended\" offset=\"{}\"/>\n", off[4])
        << fmt::format("<DataArray type=\"Float32\" Name=\"gradient\" NumberOfComponents=\"3\" format=\"appended\" offset=\"{}\"/>\n",
                       off[5])
        << "</PointData>\n</Piece>\n</UnstructuredGrid>\n<AppendedData encoding=\"raw\">\n_";
    for (const auto& a : arrays) {
      out.write(reinterpret_cast<const char*>(&a.bytes), 8);
      out.write(static_cast<const char*>(a.p), static_cast<std::streamsize>(a.bytes));
    }
    out << "\n</AppendedData>\n</VTKFile>\n";
  });
}

}  // namespace adaptiso
