// Prepares a generated sphere through the installed library and prints what it found; the test
// checks the numbers against the analytic sphere.
#include <adaptiso/extractor.hpp>
#include <adaptiso/prepare.hpp>
#include <adaptiso/synthetic.hpp>
#include <adaptiso/version.hpp>
#include <cstdio>
#include <memory>

int main() {
  const adaptiso::Volume v = adaptiso::make_synthetic("sphere", 32, adaptiso::ScalarType::i16);
  adaptiso::PrepareOptions o;
  o.max_error = 0.05;
  o.relative = true;
  auto grid = std::make_shared<const adaptiso::PreparedGrid>(adaptiso::prepare(v, o));
  adaptiso::Extractor ex(grid);
  ex.extract(700);
  const adaptiso::Mesh& m = ex.mesh();
  std::printf("adaptiso %s: %zu triangles, area %.3f, volume %.3f\n", ADAPTISO_VERSION, m.triangle_count(), adaptiso::mesh_area(m),
              adaptiso::mesh_volume(m));
  return m.triangle_count() > 0 ? 0 : 1;
}
