// A CGAL AABB tree over a mesh's triangles, for point-to-surface distances (surface_distance.cpp
// measures with it, simplify.cpp checks with it).
#pragma once
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <array>
#include <vector>

namespace adaptiso::detail {

using TreeKernel = CGAL::Simple_cartesian<double>;
using TreeTriangle = TreeKernel::Triangle_3;
using TriangleTree =
    CGAL::AABB_tree<CGAL::AABB_traits<TreeKernel, CGAL::AABB_triangle_primitive<TreeKernel, std::vector<TreeTriangle>::const_iterator>>>;

inline TreeKernel::Point_3 tree_point(const std::array<float, 3>& p) { return {p[0], p[1], p[2]}; }

}  // namespace adaptiso::detail
