// Measures of a triangle mesh (see mesh.hpp).
#include "adaptiso/mesh.hpp"

#include <cmath>

namespace adaptiso {

double mesh_area(const Mesh& m) {
  double s = 0;
  for (const auto& t : m.triangles) {
    const auto &a = m.positions[t[0]], &b = m.positions[t[1]], &c = m.positions[t[2]];
    double u[3], v[3];
    for (int k = 0; k < 3; ++k) u[k] = double(b[k]) - a[k], v[k] = double(c[k]) - a[k];
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
    s += 0.5 * std::sqrt(x * x + y * y + z * z);
  }
  return s;
}

double mesh_volume(const Mesh& m) {
  double s = 0;
  for (const auto& t : m.triangles) {
    const auto &a = m.positions[t[0]], &b = m.positions[t[1]], &c = m.positions[t[2]];
    s += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) - double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
          double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) /
         6.0;
  }
  return s;
}

}  // namespace adaptiso
