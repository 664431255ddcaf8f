#include "adaptiso/point_cloud.hpp"

#include <fmt/format.h>
#include <cstring>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

namespace {

// count points; point(n, ijk, value) gives the n-th point's voxel index and value.
template <class PointAt>
void write_points(const std::string& path, const Volume& geometry, std::size_t count, PointAt point) {
  const Volume& v = geometry;
  write_file_atomically(path, [&](std::ostream& out) {
    out << "ply\nformat binary_little_endian 1.0\ncomment adaptiso kept vertices (world coordinates)\n"
        << fmt::format("element vertex {}\n", count)
        << "property float x\nproperty float y\nproperty float z\nproperty int i\nproperty int j\nproperty int k\n"
           "property float value\nend_header\n";
    std::vector<char> buf;
    buf.reserve(1 << 20);
    for (std::size_t n = 0; n < count; ++n) {
      std::int32_t ijk[3];
      double value;
      point(n, ijk, value);
      Vec3 w = v.voxel_to_world(ijk[0], ijk[1], ijk[2]);
      float rec[7];
      for (int a = 0; a < 3; ++a) rec[a] = static_cast<float>(w[a]);
      std::memcpy(&rec[3], ijk, 12);
      rec[6] = static_cast<float>(value);
      buf.insert(buf.end(), reinterpret_cast<char*>(rec), reinterpret_cast<char*>(rec) + sizeof rec);
      if (buf.size() > (1 << 20) - 64) {
        out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
        buf.clear();
      }
    }
    out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
  });
}

}  // namespace

void write_points_ply(const std::string& path, const Volume& v, const std::vector<std::int64_t>& kept) {
  write_points(path, v, kept.size(), [&](std::size_t n, std::int32_t* ijk, double& value) {
    const std::int64_t idx = kept[n];
    ijk[0] = static_cast<std::int32_t>(idx % v.dims[0]);
    ijk[1] = static_cast<std::int32_t>((idx / v.dims[0]) % v.dims[1]);
    ijk[2] = static_cast<std::int32_t>(idx / (v.dims[0] * v.dims[1]));
    value = v.at(idx);
  });
}

void write_points_ply(const std::string& path, const TetGrid& grid) {
  Volume geometry;  // geometry only: no voxels
  geometry.dims = grid.source.volume_box();
  geometry.spacing = grid.source.spacing;
  geometry.origin = grid.source.origin;
  geometry.direction = grid.source.direction;
  // A padded lattice's copies of the last slices are no voxels of the volume: left out.
  std::vector<std::uint32_t> inside;
  if (grid.source.padded())
    for (std::uint32_t v = 0; v < grid.vertex_count(); ++v)
      if (grid.in_volume_box(v)) inside.push_back(v);
  const std::size_t count = grid.source.padded() ? inside.size() : grid.vertex_count();
  write_points(path, geometry, count, [&](std::size_t n, std::int32_t* ijk, double& value) {
    const std::uint32_t v = grid.source.padded() ? inside[n] : static_cast<std::uint32_t>(n);
    for (int a = 0; a < 3; ++a) ijk[a] = static_cast<std::int32_t>(grid.ijk[v][a]);
    value = grid.values[v];
  });
}

}  // namespace adaptiso
