#include "adaptiso/point_cloud.hpp"

#include <cstring>
#include <fmt/format.h>

#include "adaptiso/atomic_file.hpp"

namespace adaptiso {

void write_points_ply(const std::string& path, const Volume& v, const std::vector<std::int64_t>& kept) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << "ply\nformat binary_little_endian 1.0\ncomment adaptiso kept vertices (world coordinates)\n"
        << fmt::format("element vertex {}\n", kept.size())
        << "property float x\nproperty float y\nproperty float z\nproperty int i\nproperty int j\nproperty int k\n"
           "property float value\nend_header\n";
    std::vector<char> buf;
    buf.reserve(1 << 20);
    for (std::int64_t idx : kept) {
      std::int32_t ijk[3] = {static_cast<std::int32_t>(idx % v.dims[0]), static_cast<std::int32_t>((idx / v.dims[0]) % v.dims[1]),
                             static_cast<std::int32_t>(idx / (v.dims[0] * v.dims[1]))};
      Vec3 w = v.voxel_to_world(ijk[0], ijk[1], ijk[2]);
      float rec[7];
      for (int a = 0; a < 3; ++a) rec[a] = static_cast<float>(w[a]);
      std::memcpy(&rec[3], ijk, 12);
      rec[6] = static_cast<float>(v.at(idx));
      buf.insert(buf.end(), reinterpret_cast<char*>(rec), reinterpret_cast<char*>(rec) + sizeof rec);
      if (buf.size() > (1 << 20) - 64) {
        out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
        buf.clear();
      }
    }
    out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
  });
}

}  // namespace adaptiso
