// The .adg grid file (see grid_file.hpp) and the .vtu export.
#include "adaptiso/grid_file.hpp"

#include <libdeflate.h>

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>
#include <zlib.h>
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <span>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/select_shares.hpp"
#include "grid/share_agree.hpp"
#include "io/grid_check.hpp"
#include "io/grid_file_stream.hpp"
#include "util/big_array.hpp"
#include "util/memory.hpp"
#include "volume/io_util.hpp"

namespace adaptiso {
namespace {

constexpr char kMagic[16] = {'A', 'D', 'A', 'P', 'T', 'I', 'S', 'O', '-', 'G', 'R', 'I', 'D', 0, 0, 0};
// Version 4: the index lists' equal keys may come in any order (earlier ones: by tetrahedron id),
// so a build that reads 3 does not call a version 4 file corrupt. The layout is version 3's.
// Version 5: the checksum covers every byte. Up to 4 it restarted at every empty array (the
// writer passed the CRC a null pointer, which zlib and libdeflate answer with the initial value),
// so an empty index list, or an empty grid, left whatever preceded it unprotected.
// Version 6: a file without its index gives the depth to build it at (earlier ones: 0, built at the
// default depth), so a grid prepared at another depth loads as it was prepared.
constexpr std::uint32_t kVersion = 6, kLastRestartingChecksum = 4, kFirstDepthWithoutIndex = 6;
constexpr std::uint64_t kHeaderV1 = 48, kHeader = 64;
constexpr std::uint32_t kHasIndex = 1, kHasHierarchy = 2, kHasDisplacement = 4;
constexpr std::uint64_t kHierarchyHeader = 40;  // i32 root size, u8 thresholds ×2, u16 reserved, f64 ×4
constexpr std::uint64_t kNodeBytes = 24;        // f64 split, u64 begin, u64 end

// The layout's bytes per vertex, and what follows the metadata for these counts (the checksum
// included): what the loader checks a file's size against.
std::uint64_t bytes_per_vertex_on_disk(bool hierarchy, bool moves) { return 12 + 8 + 12 + (hierarchy ? 1 + 8 : 0) + (moves ? 1 : 0); }
std::uint64_t body_bytes(std::uint64_t N, std::uint64_t T, std::uint64_t nodes, std::uint64_t E, bool hierarchy, bool moves) {
  return N * bytes_per_vertex_on_disk(hierarchy, moves) + T * 16 + nodes * kNodeBytes + E * 8 + (hierarchy ? kHierarchyHeader : 0) + 4;
}

// What a load holds at its peak, before it reads a byte: the vertices (as on disk); with the
// tetrahedra, them and their index, and either a stored index's check (a slot a tetrahedron) or the
// build's sort (its scratch: up to 16 bytes an entry of the nodes sorted at once, within 1 GiB);
// for a bisection hierarchy its check's bitmap (a quarter byte a voxel, bounded here by 8 bytes a
// vertex) and 2 bytes a vertex. The CT bunny's whole load: 2.6 GB estimated, 2.45 GB measured.
std::uint64_t load_bytes(std::uint64_t N, std::uint64_t T, std::uint64_t E, std::uint64_t nodes, std::uint32_t depth, bool hierarchy,
                         bool moves, bool keep_tets, bool keep_index) {
  std::uint64_t bytes = N * bytes_per_vertex_on_disk(hierarchy, moves) + (hierarchy ? N * 10 : 0);
  if (keep_tets) bytes += T * 16;
  if (keep_index) {
    const std::uint64_t entries = E ? E : T;  // without an index, every tetrahedron at most
    const std::uint64_t check = E ? T * 4 : std::min<std::uint64_t>(kDefaultIndexScratch, entries * 16);
    // A built index has at most twice as many nodes as entries (its depth is reduced to them).
    const std::uint64_t tree_nodes = E ? nodes : std::min<std::uint64_t>((std::uint64_t{2} << depth) - 1, 2 * entries + 1);
    bytes += entries * 8 + tree_nodes * sizeof(IntervalTree::Node) + check;
  }
  return bytes;
}

nlohmann::json source_json(const GridSource& s) {
  nlohmann::json j = {
      {"dims", s.dims}, {"spacing", s.spacing}, {"origin", s.origin},       {"direction", s.direction}, {"type", s.type}, {"min", s.min},
      {"max", s.max},   {"method", s.method},   {"max_error", s.max_error}, {"threshold", s.threshold}, {"file", s.file}};
  // Only a padded lattice writes it: files of unpadded grids keep their bytes. A build older than
  // the padding ignores it and shows the padding's surfaces unclipped.
  if (s.padded()) j["volume_dims"] = s.volume_dims;
  return j;
}

class CrcWriter {
public:
  explicit CrcWriter(std::ostream& o) : out_(o) {}
  void write(const void* p, std::size_t n) {
    if (n) crc_ = libdeflate_crc32(crc_, p, n);  // an empty array's null pointer would restart it
    written_ += n;
    out_.write(static_cast<const char*>(p), static_cast<std::streamsize>(n));
  }
  template <class T>
  void put(const T& x) {
    write(&x, sizeof x);
  }
  std::uint32_t crc() const { return crc_; }
  std::uint64_t written() const { return written_; }

private:
  std::ostream& out_;
  std::uint32_t crc_ = 0;
  std::uint64_t written_ = 0;
};

}  // namespace

namespace {

// A grid file's parts, in their order. Its counts come first (in the header): the streaming
// writer knows the index's shape before the index exists.
class GridFileWriter {
public:
  explicit GridFileWriter(std::ostream& out) : out_(out), w_(out) {}

  // Header and metadata. Timings and memory peaks vary from run to run, and the index's shape
  // is known only once the tetrahedra are (a file written as they are made: GridFileStream): the
  // file keeps the rest of the statistics, so the same input and options give the same bytes.
  // Without an index, `depth` is the depth loading builds it at.
  void head(const PrepareStats& st, const GridSource& source, std::uint64_t N, std::uint64_t T, const BisectionHierarchy* h,
            const IntervalTreeShape* index, std::uint32_t depth) {
    nlohmann::json stats = nlohmann::json::parse(to_json(st));
    for (const char* key : {"seconds", "peak_bytes", "index_depth", "grid_bytes_per_vertex", "tree_depth"}) stats.erase(key);
    const std::string m = nlohmann::json{{"source", source_json(source)}, {"prepare", stats}}.dump();
    const bool moves = h && !h->displacement_code.empty();
    w_.write(kMagic, 16);
    w_.put(kVersion);
    w_.put((index ? kHasIndex : 0) | (h ? kHasHierarchy : 0) | (moves ? kHasDisplacement : 0));
    w_.put(static_cast<std::uint64_t>(m.size()));
    w_.put(N);
    w_.put(T);
    w_.put(static_cast<std::uint64_t>(index ? index->entries : 0));
    w_.put(index ? index->depth : depth);
    w_.put(std::uint32_t{0});
    w_.write(m.data(), m.size());
  }
  void vertices(const TetGrid& grid) {
    w_.write(grid.ijk.data(), grid.ijk.size() * sizeof grid.ijk[0]);
    w_.write(grid.values.data(), grid.values.size() * sizeof(double));
    w_.write(grid.gradients.data(), grid.gradients.size() * sizeof grid.gradients[0]);
  }
  void tetrahedra(std::span<const std::array<std::uint32_t, 4>> tets) { w_.write(tets.data(), tets.size_bytes()); }
  void index(const IntervalTree& index) {
    for (const auto& n : index.nodes) {
      w_.put(n.split);
      w_.put(n.begin);
      w_.put(n.end);
    }
    w_.write(index.by_min.data(), index.by_min.size() * 4);
    w_.write(index.by_max.data(), index.by_max.size() * 4);
  }
  void hierarchy(const BisectionHierarchy& h) {
    w_.put(h.root_size);
    w_.put(h.error_threshold);
    w_.put(h.displacement_threshold);
    w_.put(std::uint16_t{0});
    w_.put(h.codes.scale);
    w_.put(h.codes.zero);
    w_.put(h.displacement_codes.scale);
    w_.put(h.displacement_codes.zero);
    w_.write(h.error_code.data(), h.error_code.size());
    if (!h.displacement_code.empty()) w_.write(h.displacement_code.data(), h.displacement_code.size());
    w_.write(h.value_span.data(), h.value_span.size() * 8);
  }
  // The checksum, not in the count of bytes written (written()), being no part of itself.
  void checksum() {
    const std::uint32_t c = w_.crc();
    out_.write(reinterpret_cast<const char*>(&c), 4);
  }
  std::uint64_t written() const { return w_.written(); }

private:
  std::ostream& out_;
  CrcWriter w_;
};

// The depth a file without its index gives loading to build it at: the depth asked for, which
// loading reduces as the build did (a file written as its grid is made knows no other), unless the
// grid's index was built at another (then its own).
std::uint32_t depth_to_build(const PreparedGrid& p) {
  const std::uint32_t asked = std::min(p.stats.tree_depth, kMaxTreeDepth);
  if (p.index.nodes.empty() || p.index.depth == asked) return asked;
  if (p.index.depth < asked && interval_tree_shape(p.grid, asked).depth == p.index.depth) return asked;  // reduced
  return p.index.depth;
}

}  // namespace

void save_grid(const PreparedGrid& p, const std::string& path, bool with_index) {
  const IntervalTreeShape shape{p.index.depth, p.index.entries()};
  const std::uint32_t depth = with_index ? p.index.depth : depth_to_build(p);
  const BisectionHierarchy* h = p.hierarchy ? &*p.hierarchy : nullptr;
  write_file_atomically(path, [&](std::ostream& out) {
    GridFileWriter w(out);
    w.head(p.stats, p.grid.source, p.grid.vertex_count(), p.grid.tet_count(), h, with_index ? &shape : nullptr, depth);
    w.vertices(p.grid);
    w.tetrahedra(p.grid.tets);
    if (with_index) w.index(p.index);
    if (h) w.hierarchy(*h);
    w.checksum();
  });
}

namespace detail {

struct GridFileStream::Writer {
  explicit Writer(std::ostream& out) : w(out) {}
  GridFileWriter w;
};

GridFileStream::GridFileStream(std::ostream& out) : writer_(std::make_unique<Writer>(out)) {}
GridFileStream::~GridFileStream() = default;

void GridFileStream::head(const PrepareStats& stats, const TetGrid& vertices, const BisectionHierarchy& hierarchy) {
  writer_->w.head(stats, vertices.source, vertices.vertex_count(), stats.tetrahedra, &hierarchy, nullptr,
                  std::min(stats.tree_depth, kMaxTreeDepth));
  writer_->w.vertices(vertices);
}

void GridFileStream::tetrahedra(std::span<const std::array<std::uint32_t, 4>> tets) { writer_->w.tetrahedra(tets); }

void GridFileStream::finish(const BisectionHierarchy& hierarchy) {
  writer_->w.hierarchy(hierarchy);
  writer_->w.checksum();
}

}  // namespace detail

namespace {

// The processes of a shared load (load_grid_shared) read the same bytes, and the same parts of
// them, or all refuse alike: what they combine next, and how often, follows from both. Called with
// the file's size, the parts and the header before anything is combined, and again with the
// checksum.
template <std::size_t N>
void agree_same_file(ShareTransport& t, const std::string& path, const std::array<std::uint64_t, N>& mine) {
  std::array<std::uint64_t, N> zero = mine;
  std::int64_t other = detail::share::differs_from_zero(t, zero) ? t.process() : -1;
  detail::share::combine_at_zero(t, std::span(&other, 1), [](std::int64_t& own, std::int64_t theirs) {
    if (own < 0) own = theirs;
  });
  if (other >= 0)
    throw InputError(
        fmt::format("{}: process {} read other bytes than process 0 (another size, header or checksum) or asked for other parts of "
                    "them: every process must load the same parts of the same grid file",
                    path, other));
}

// load_grid, remembering what the hierarchy's walk checked (`remember`), or taking a walk of the
// same bytes as checked (`walked`: the same size and checksum) instead of walking again.
// `file` is opened, `named` (when given) named in messages: the messages of a shared load's
// processes go to every process, so they carry the user's name, not a process's own descriptor.
PreparedGrid load_checked(const std::string& file, GridParts parts, detail::HierarchyWalk* remember, const detail::HierarchyWalk* walked,
                          const Progress& progress, ShareTransport* share = nullptr, const std::string& named = {}) {
  const std::string& path = named.empty() ? file : named;
  if (share && share->processes() <= 1) share = nullptr;  // one process: nothing to share
  std::ifstream in;
  std::uint64_t size = 0, M = 0, N = 0, T = 0, E = 0, header = kHeaderV1;
  unsigned char h[kHeader] = {};
  std::uint32_t version = 0, flags = 0, depth = 0;
  auto read_header = [&] {
    try {
      detail::file_size_or_throw(file);  // a FIFO or device would block or never end
    } catch (const InputError& e) {
      std::string what = e.what();
      if (what.starts_with(file)) what.replace(0, file.size(), path);
      throw InputError(what);
    }
    in.open(file, std::ios::binary | std::ios::ate);
    if (!in) throw InputError(fmt::format("{}: cannot open grid file", path));
    size = static_cast<std::uint64_t>(in.tellg());
    in.seekg(0);
    if (size < kHeaderV1 + 4) throw InputError(fmt::format("{}: not an adaptiso grid file (too short)", path));
    in.read(reinterpret_cast<char*>(h), kHeaderV1);
    if (std::memcmp(h, kMagic, 16) != 0) throw InputError(fmt::format("{}: not an adaptiso grid file (bad magic)", path));
    std::memcpy(&version, h + 16, 4);
    std::memcpy(&flags, h + 20, 4);
    std::memcpy(&M, h + 24, 8);
    std::memcpy(&N, h + 32, 8);
    std::memcpy(&T, h + 40, 8);
    if (version < 1 || version > kVersion)
      throw InputError(fmt::format("{}: grid file version {} is not supported (this build reads 1 to {})", path, version, kVersion));
    if (version >= 2) {
      header = kHeader;
      if (size < kHeader + 4) throw InputError(fmt::format("{}: grid file is truncated", path));
      in.read(reinterpret_cast<char*>(h + kHeaderV1), kHeader - kHeaderV1);
      std::memcpy(&E, h + 48, 8);
      std::memcpy(&depth, h + 56, 4);
    }
  };
  if (share) {
    std::exception_ptr failed;
    try {
      read_header();
    } catch (const InputError&) {
      failed = std::current_exception();
    }
    detail::share::agree_first_failure(*share, failed);
  } else {
    read_header();
  }
  // The header every process of a shared load read, and the parts each asks for, before any of
  // them refuses what differs between them (the sections read, and so what is combined, follow).
  if (share) {
    std::array<std::uint64_t, 2 + kHeader / 8> id{size, static_cast<std::uint64_t>(parts)};
    std::memcpy(&id[2], h, kHeader);
    agree_same_file(*share, path, id);
  }
  if (version >= 2) {
    std::uint32_t reserved;
    std::memcpy(&reserved, h + 60, 4);
    if (reserved != 0) throw InputError(fmt::format("{}: grid file is corrupt (reserved header bytes are not zero)", path));
  }
  const bool has_index = version >= 2 && (flags & kHasIndex);
  const bool has_hierarchy = version >= 3 && (flags & kHasHierarchy), has_moves = version >= 3 && (flags & kHasDisplacement);
  const std::uint32_t known = version >= 3 ? (kHasIndex | kHasHierarchy | kHasDisplacement) : kHasIndex;
  // Without an index, a depth to build it at (from version 6; none before).
  const std::uint32_t most_depth = has_index ? 30 : version >= kFirstDepthWithoutIndex ? kMaxTreeDepth : 0;
  if ((version == 1 && flags != 0) || (version >= 2 && (flags & ~known)) || depth > most_depth || (!has_index && E) ||
      (has_moves && !has_hierarchy))
    throw InputError(fmt::format("{}: grid file is corrupt (bad header flags)", path));
  const std::uint64_t nodes = has_index ? (std::uint64_t{2} << depth) - 1 : 0;
  // Without an index, the depth loading builds it at.
  const std::uint32_t build_depth = version >= kFirstDepthWithoutIndex ? depth : kDefaultTreeDepth;
  // The size the counts imply must be the file's size; checked without overflow before allocating.
  const std::uint64_t per_vertex = bytes_per_vertex_on_disk(has_hierarchy, has_moves), per_tet = 16;
  if (M > size || N > size / per_vertex || T > size / per_tet || E > T || nodes > size / kNodeBytes ||
      header + M + body_bytes(N, T, nodes, E, has_hierarchy, has_moves) != size)
    throw InputError(fmt::format("{}: grid file is truncated or corrupt (size {} does not match its header)", path, size));
  if (N > std::numeric_limits<std::uint32_t>::max() || T > std::numeric_limits<std::uint32_t>::max())
    throw InputError(fmt::format("{}: too many vertices or tetrahedra", path));
  const bool whole = parts == GridParts::all || (parts == GridParts::hierarchy_or_all && !has_hierarchy);
  const bool keep_tets = whole || parts == GridParts::tetrahedra, keep_index = whole;
  if (!keep_tets && !has_hierarchy)
    throw InputError(fmt::format(
        "{}: has no bisection hierarchy (a Delaunay grid, or an older file): surfaces at a distance or at another error need one", path));
  detail::check_memory(load_bytes(N, T, E, nodes, build_depth, has_hierarchy, has_moves, keep_tets, keep_index),
                       fmt::format("{}: loading a grid of {} vertices and {} tetrahedra", path, N, T), "",
                       "free memory or raise the memory limit");
  std::uint32_t crc = libdeflate_crc32(0, h, header);
  const bool restarting = version <= kLastRestartingChecksum;
  std::uint64_t read_bytes = header;
  report(progress, "read grid", 0);
  // In slices of 64 MiB, so the progress moves (the bunny's tetrahedra are 0.87 GB).
  auto read = [&](void* p, std::size_t n) {
    if (n == 0 && restarting && !p) crc = 0;  // what the older writers did
    for (std::size_t at = 0; at < n;) {
      const std::size_t step = std::min<std::size_t>(n - at, std::size_t{64} << 20);
      char* slice = static_cast<char*>(p) + at;
      in.read(slice, static_cast<std::streamsize>(step));
      if (static_cast<std::size_t>(in.gcount()) != step) throw InputError(fmt::format("{}: grid file is truncated", path));
      crc = libdeflate_crc32(crc, slice, step);
      at += step;
      read_bytes += step;
      report(progress, "read grid", static_cast<double>(read_bytes) / static_cast<double>(size));
    }
  };
  // An array read for the checksum only, a slice at a time (an empty one as read() takes it).
  auto pass_whole = [&](std::uint64_t n) {
    if (n == 0) return read(nullptr, 0);
    std::vector<unsigned char> slice(std::min<std::uint64_t>(n, std::uint64_t{8} << 20));
    for (std::uint64_t done = 0; done < n;) {
      const std::uint64_t step = std::min<std::uint64_t>(slice.size(), n - done);
      read(slice.data(), step);
      done += step;
    }
  };
  // In a shared load each process reads its P-th of such an array, and the pieces' checksums are
  // combined in order (zlib's crc32_combine64): the CT bunny's tetrahedra, 0.87 GB of its 1.3 GB
  // grid file, are read only for the checksum when loading what the distance queries need.
  // (Files of version 4 and older restart their checksum at empty arrays: read whole.)
  const bool shared_reads = share && !restarting;
  auto pass_over = [&](std::uint64_t n) {
    if (n == 0 || !shared_reads) return pass_whole(n);
    const auto P = static_cast<std::uint64_t>(share->processes()), me = static_cast<std::uint64_t>(share->process());
    auto begin = [&](std::uint64_t q) { return detail::share::part_begin(n, P, q); };
    const auto start = static_cast<std::uint64_t>(in.tellg());
    std::vector<std::uint32_t> pieces(P, 0);  // each piece's checksum from 0; the others' are 0 here
    if (begin(me + 1) > begin(me)) {
      const std::uint32_t before = crc;
      crc = 0;
      in.seekg(static_cast<std::streamoff>(start + begin(me)));
      pass_whole(begin(me + 1) - begin(me));
      pieces[me] = crc;
      crc = before;
    }
    in.seekg(static_cast<std::streamoff>(start + n));
    read_bytes += n - (begin(me + 1) - begin(me));
    detail::share::combine_at_zero(*share, std::span(pieces), [](std::uint32_t& own, std::uint32_t theirs) { own |= theirs; });
    for (std::uint64_t q = 0; q < P; ++q)
      crc = static_cast<std::uint32_t>(crc32_combine64(crc, pieces[q], static_cast<z_off64_t>(begin(q + 1) - begin(q))));
  };
  std::string meta(M, '\0');
  read(meta.data(), M);
  PreparedGrid p;
  TetGrid& grid = p.grid;
  detail::resize_big(grid.ijk, N);
  detail::resize_big(grid.values, N);
  detail::resize_big(grid.gradients, N);
  if (keep_tets) detail::resize_big(grid.tets, T);
  read(grid.ijk.data(), N * 12);
  read(grid.values.data(), N * 8);
  read(grid.gradients.data(), N * 12);
  if (keep_tets)
    read(grid.tets.data(), T * 16);
  else
    pass_over(T * 16);
  IntervalTree tree;
  if (has_index && !keep_index) {
    pass_over(nodes * kNodeBytes);
    pass_over(E * 4);  // by_min
    pass_over(E * 4);  // by_max
  } else if (has_index) {
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
  std::uint16_t hierarchy_reserved = 0;  // refused once the processes agree on the bytes read
  if (has_hierarchy) {
    BisectionHierarchy& hh = p.hierarchy.emplace();
    std::uint16_t reserved = 0;
    read(&hh.root_size, 4);
    read(&hh.error_threshold, 1);
    read(&hh.displacement_threshold, 1);
    read(&reserved, 2);
    hierarchy_reserved = reserved;
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
  report(progress, "read grid", 1);
  // Processes of a shared load that read other bytes would each find another fault here (their
  // checksums combine pieces of each other's files): they agree on the file's checksum first.
  if (share) agree_same_file(*share, path, std::array<std::uint64_t, 2>{size, stored});
  if (hierarchy_reserved != 0) throw InputError(fmt::format("{}: grid file is corrupt (reserved hierarchy bytes are not zero)", path));
  if (static_cast<std::uint32_t>(crc) != stored) throw InputError(fmt::format("{}: grid file is corrupt (checksum mismatch)", path));
  auto j = nlohmann::json::parse(meta, nullptr, false);
  if (j.is_discarded() || !j.is_object() || !j.contains("source"))
    throw InputError(fmt::format("{}: grid metadata is not valid JSON", path));
  grid.source = detail::grid_source_from_json(j["source"], path);
  if (j.contains("prepare")) {
    if (!j["prepare"].is_object()) throw InputError(fmt::format("{}: grid metadata is invalid (\"prepare\" is not an object)", path));
    try {
      p.stats = prepare_stats_from_json(j["prepare"].dump());
    } catch (const nlohmann::json::exception& e) {
      throw InputError(fmt::format("{}: grid metadata is invalid (\"prepare\": {})", path, e.what()));
    }
  }
  // Before the index's check, which costs more: what every later walk trusts.
  if (walked && keep_tets && p.hierarchy && walked->file_bytes == size && walked->checksum == stored) {
    detail::check_tets_walked(p, path, *walked);
  } else {
    detail::check_grid(p, path, keep_tets ? std::nullopt : std::optional<std::uint64_t>(T), remember, progress, share);
    if (remember) {
      remember->file_bytes = size;
      remember->checksum = stored;
    }
  }
  // A padded lattice's counts from its checked vertices, not from the metadata: until 2026-11-29
  // prepare counted the copies past the far faces as kept voxels.
  if (grid.source.padded()) {
    p.stats.kept = grid.volume_vertex_count();
    p.stats.vertices = grid.vertex_count();
  }
  p.stats.tree_depth = has_index ? depth : build_depth;
  if (!keep_tets) {
    p.index = IntervalTree{};
    if (p.stats.tetrahedra == 0) p.stats.tetrahedra = T;  // an older file's metadata without them
  } else if (!keep_index) {
    p.index = IntervalTree{};
  } else if (has_index) {
    validate_interval_tree(tree, grid, path, progress);
    finish_interval_tree(tree, grid);
    p.index = std::move(tree);
  } else {
    report(progress, "build index", 0);
    p.index = build_interval_tree(grid, build_depth);
    report(progress, "build index", 1);
  }
  if (keep_index) {  // the index's figures from the index (files since 2026-11-30 leave them out)
    p.stats.index_depth = p.index.depth;
    p.stats.grid_bytes_per_vertex = grid_bytes_per_vertex(grid, p.index);
  }
  return p;
}

}  // namespace

PreparedGrid load_grid(const std::string& path, GridParts parts, const Progress& progress) {
  return load_checked(path, parts, nullptr, nullptr, progress);
}

// Through OpenGridFile whatever the caller: every process then takes the same steps together
// (opening agreed, then the load's), whether it asked for the file held open or not.
PreparedGrid load_grid_shared(const std::string& path, GridParts parts, ShareTransport& transport, const Progress& progress) {
  return OpenGridFile(path, &transport).load(parts, progress, &transport);
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
  // A padded lattice (tet_grid.hpp) tiles more than the volume: its vertices say which are the
  // volume's voxels, so a viewer can threshold the copies of the last slices away.
  std::vector<std::uint8_t> in_volume;
  if (grid.source.padded()) {
    in_volume.resize(n);
    for (std::uint64_t v = 0; v < n; ++v) in_volume[v] = grid.in_volume_box(static_cast<std::uint32_t>(v));
    arrays.push_back({in_volume.data(), n});
  }
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
        << (in_volume.empty() ? std::string()
                              : fmt::format("<DataArray type=\"UInt8\" Name=\"in_volume\" format=\"appended\" offset=\"{}\"/>\n", off[6]))
        << "</PointData>\n</Piece>\n</UnstructuredGrid>\n<AppendedData encoding=\"raw\">\n_";
    for (const auto& a : arrays) {
      out.write(reinterpret_cast<const char*>(&a.bytes), 8);
      out.write(static_cast<const char*>(a.p), static_cast<std::streamsize>(a.bytes));
    }
    out << "\n</AppendedData>\n</VTKFile>\n";
  });
}

OpenGridFile::OpenGridFile(std::string path, ShareTransport* share) : path_(std::move(path)) {
  if (share && share->processes() <= 1) share = nullptr;  // one process: nothing to agree
  std::exception_ptr failed;
  try {
    fd_ = ::open(path_.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);  // a FIFO would wait for a writer
    if (fd_ < 0) {
      detail::file_size_or_throw(path_);  // its message for a missing file or a folder
      throw InputError(fmt::format("{}: cannot open grid file", path_));
    }
  } catch (const InputError&) {
    if (!share) throw;
    failed = std::current_exception();
  }
  if (share) {
    try {
      detail::share::agree_first_failure(*share, failed);
    } catch (...) {
      if (fd_ >= 0) ::close(fd_);  // no destructor runs for a constructor that throws
      throw;
    }
  }
}

OpenGridFile::~OpenGridFile() { ::close(fd_); }

PreparedGrid OpenGridFile::load(GridParts parts, const Progress& progress, ShareTransport* share) const {
  const std::string fd_path = "/proc/self/fd/" + std::to_string(fd_);
  try {
    if (share && share->processes() > 1) return load_checked(fd_path, parts, nullptr, nullptr, progress, share, path_);
    if (parts == GridParts::all || parts == GridParts::tetrahedra) return load_checked(fd_path, parts, nullptr, walk_.get(), progress);
    auto walk = std::make_unique<detail::HierarchyWalk>();
    PreparedGrid p = load_checked(fd_path, parts, walk.get(), nullptr, progress);
    if (!walk->leaves.empty()) walk_ = std::move(walk);  // a bisection grid's walk
    return p;
  } catch (const InputError& e) {  // the user's name for the file, not the descriptor's
    std::string what = e.what();
    if (what.starts_with(fd_path)) what.replace(0, fd_path.size(), path_);
    throw InputError(what);
  }
}

}  // namespace adaptiso
