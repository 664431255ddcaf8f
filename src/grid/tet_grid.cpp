// The grid's description of its source (see tet_grid.hpp).
#include "adaptiso/tet_grid.hpp"

namespace adaptiso {

GridSource grid_source(const Volume& v, const ValueRange& range) {
  GridSource s;
  s.dims = v.dims;
  s.spacing = v.spacing;
  s.origin = v.origin;
  s.direction = v.direction;
  s.type = std::string(scalar_name(v.type));
  s.min = range.min;
  s.max = range.max;
  return s;
}

}  // namespace adaptiso
