// The longest-edge bisection hierarchy on the voxel lattice, as diamonds (Maubach's bisection of
// the Kuhn cube; the diamond view of Gregorski, Duchaineau, Lindstrom, Pascucci and Joy 2002).
// Internal to the bisection grid (bisection_errors.cpp, bisection.cpp, bisection_coarsen.cpp) and
// its queries.
//
// The root cube [0,S]³ (S = 2^k) is split into 6 tetrahedra around its main diagonal; every
// tetrahedron is split at the midpoint of its longest edge (unique in this hierarchy), down to the
// Kuhn tetrahedra of the unit cubes, whose longest edge (a unit cube's diagonal) has no lattice
// midpoint. Each lattice point that is not a corner of the root cube is the midpoint of exactly one
// refinement edge: the centre of a *diamond*, the tetrahedra sharing that edge, which are split
// together to stay conforming. With h = 2^s the largest power of two dividing every coordinate
// (0 counts as divisible by all), a centre whose three coordinates are odd multiples of h is a
// cube centre (the diagonal of a cube of side 2h, 6 tetrahedra), two odd multiples a face centre
// (a face diagonal, 4 tetrahedra in the 2 cubes beside the face), one an edge midpoint (a cube
// edge, 8 tetrahedra in the 4 cubes around it). The cubes of side 2h are aligned to multiples of
// 2h; a cube's diagonal runs from its corner at odd multiples of 2h (the parent cube's centre) to
// the opposite one, so neighbouring cubes mirror each other and every face diagonal is shared.
//
// Refinement order, coarse to fine: at each scale h = S/2, S/4, …, 1 the cube centres, then the
// face centres, then the edge midpoints. A diamond's children are the diamonds of its tetrahedra's
// halves: a cube centre's 6 face centres (c ± h·e_a), a face centre's 4 edge midpoints (c ± h
// along its two in-face axes), an edge midpoint's 8 cube centres at h/2 (c + h/2·(±1,±1,±1)). Its
// parents are the inverse relation: splitting a diamond requires its parents split (conformity).
#pragma once
#include <array>
#include <bit>
#include <cstdint>

namespace adaptiso::detail {

using Coord = std::array<std::int32_t, 3>;

enum class DiamondKind : std::uint8_t { cube = 0, face = 1, edge = 2 };

struct Diamond {
  Coord c{};           // centre
  std::int32_t h = 0;  // scale: cubes of side 2h
  int s = 0;           // log2(h)
  DiamondKind kind = DiamondKind::cube;
  int axis = 0;        // face: its normal; edge: its direction; cube: unused
  bool valid = false;  // false for the corners of the root cube (no diamond)
};

// The lattice of one volume: the root cube of side S = 2^k and the volume's box [0, X_a] per axis.
struct Lattice {
  int k = 0;
  std::int32_t S = 1;
  Coord X{};                     // dims - 1 per axis
  std::int64_t nx = 0, nxy = 0;  // strides of the voxel index

  bool in_box(const Coord& c) const { return c[0] <= X[0] && c[1] <= X[1] && c[2] <= X[2] && c[0] >= 0 && c[1] >= 0 && c[2] >= 0; }
  std::int64_t index(const Coord& c) const { return c[0] + nx * c[1] + nxy * c[2]; }
};

inline int trailing_zeros(std::int32_t c) { return c == 0 ? 64 : std::countr_zero(static_cast<std::uint32_t>(c)); }

inline Diamond classify(const Coord& c, int k) {
  Diamond d;
  d.c = c;
  const int tz[3] = {trailing_zeros(c[0]), trailing_zeros(c[1]), trailing_zeros(c[2])};
  const int s = std::min({tz[0], tz[1], tz[2]});
  if (s >= k) return d;  // a corner of the root cube
  d.s = s;
  d.h = std::int32_t{1} << s;
  int odd = 0, odd_axis = 0, even_axis = 0;
  for (int a = 0; a < 3; ++a) {
    if (tz[a] == s) {
      ++odd;
      odd_axis = a;
    } else {
      even_axis = a;
    }
  }
  d.kind = odd == 3 ? DiamondKind::cube : odd == 2 ? DiamondKind::face : DiamondKind::edge;
  d.axis = odd == 2 ? even_axis : odd_axis;
  d.valid = true;
  return d;
}

// Of c ± h along one axis (c an odd multiple of h), the end at an odd multiple of 2h (a parent
// cube's centre in the cube's diagonal) and the end at an even multiple of 2h.
inline std::int32_t odd_end(std::int32_t c, std::int32_t h) { return ((c + h) / (2 * h)) & 1 ? c + h : c - h; }
inline std::int32_t even_end(std::int32_t c, std::int32_t h) { return ((c + h) / (2 * h)) & 1 ? c - h : c + h; }

// The refinement edge's two ends.
inline std::array<Coord, 2> refinement_edge(const Diamond& d) {
  Coord p = d.c, q = d.c;
  if (d.kind == DiamondKind::edge) {
    p[d.axis] -= d.h;
    q[d.axis] += d.h;
  } else {
    for (int a = 0; a < 3; ++a) {
      if (d.kind == DiamondKind::face && a == d.axis) continue;
      p[a] = odd_end(d.c[a], d.h);
      q[a] = even_end(d.c[a], d.h);
    }
  }
  return {p, q};
}

// The cubes (side 2h, by their lowest corner) holding the diamond's tetrahedra, within the root
// cube; returns how many (1, 2 or 4).
inline int diamond_cubes(const Diamond& d, std::int32_t S, Coord out[4]) {
  const std::int32_t h = d.h, L = 2 * h;
  int n = 0;
  auto add = [&](Coord m) {
    for (int a = 0; a < 3; ++a)
      if (m[a] < 0 || m[a] + L > S) return;
    out[n++] = m;
  };
  const Coord& c = d.c;
  if (d.kind == DiamondKind::cube) {
    add({c[0] - h, c[1] - h, c[2] - h});
  } else if (d.kind == DiamondKind::face) {
    Coord m{c[0] - h, c[1] - h, c[2] - h};
    m[d.axis] = c[d.axis];
    add(m);
    m[d.axis] = c[d.axis] - L;
    add(m);
  } else {
    const int j = (d.axis + 1) % 3, l = (d.axis + 2) % 3;
    for (int dj = 0; dj < 2; ++dj)
      for (int dl = 0; dl < 2; ++dl) {
        Coord m{};
        m[d.axis] = c[d.axis] - h;
        m[j] = c[j] - dj * L;
        m[l] = c[l] - dl * L;
        add(m);
      }
  }
  return n;
}

// A cube of side L at m against the box [0, X]: it straddles the box's far faces (the near faces
// at 0 are on every cube boundary), lies inside, or lies outside.
enum class CubeSide : std::uint8_t { inside, outside, straddles };
inline CubeSide cube_side(const Coord& m, std::int32_t L, const Coord& X) {
  bool inside = true;
  for (int a = 0; a < 3; ++a) {
    if (m[a] >= X[a]) return CubeSide::outside;
    if (m[a] + L > X[a]) inside = false;
  }
  if (inside) return CubeSide::inside;
  return CubeSide::straddles;
}

// Where the diamond's tetrahedra lie: any cube across the box's boundary forces the split (no
// tetrahedron may reach outside the volume); otherwise some or none of them are inside.
struct Placement {
  bool forced = false, any_inside = false;
};
inline Placement placement(const Diamond& d, const Lattice& lat) {
  Coord cubes[4];
  const int n = diamond_cubes(d, lat.S, cubes);
  Placement p;
  for (int i = 0; i < n; ++i) {
    const CubeSide side = cube_side(cubes[i], 2 * d.h, lat.X);
    p.forced |= side == CubeSide::straddles;
    p.any_inside |= side == CubeSide::inside;
  }
  return p;
}

// A diamond whose every cube lies inside the box (no checks needed for it or its children).
inline bool deep_inside(const Diamond& d, const Lattice& lat) {
  const std::int32_t reach = 2 * d.h;
  return d.c[0] + reach <= lat.X[0] && d.c[1] + reach <= lat.X[1] && d.c[2] + reach <= lat.X[2];
}

// The children's centres; returns how many (6, 4 or 8; fewer at the root cube's boundary, none for
// the edge midpoints of scale 1, whose halves are the unit Kuhn tetrahedra).
inline int children(const Diamond& d, std::int32_t S, Coord out[8]) {
  const Coord& c = d.c;
  const std::int32_t h = d.h;
  int n = 0;
  if (d.kind == DiamondKind::cube) {
    for (int a = 0; a < 3; ++a)
      for (int sgn : {-1, 1}) {
        Coord x = c;
        x[a] += sgn * h;
        out[n++] = x;
      }
  } else if (d.kind == DiamondKind::face) {
    for (int a = 0; a < 3; ++a) {
      if (a == d.axis) continue;
      for (int sgn : {-1, 1}) {
        Coord x = c;
        x[a] += sgn * h;
        out[n++] = x;
      }
    }
  } else if (h >= 2) {
    const std::int32_t g = h / 2;
    for (int i = 0; i < 8; ++i) {
      const Coord x{c[0] + (i & 1 ? g : -g), c[1] + (i & 2 ? g : -g), c[2] + (i & 4 ? g : -g)};
      if (x[0] >= 0 && x[1] >= 0 && x[2] >= 0 && x[0] <= S && x[1] <= S && x[2] <= S) out[n++] = x;
    }
  }
  return n;
}

// The parents' centres (the diamonds that must be split before this one); returns how many.
inline int parents(const Diamond& d, std::int32_t S, Coord out[4]) {
  const Coord& c = d.c;
  const std::int32_t h = d.h;
  int n = 0;
  auto add = [&](const Coord& x) {
    for (int a = 0; a < 3; ++a)
      if (x[a] < 0 || x[a] > S) return;
    out[n++] = x;
  };
  if (d.kind == DiamondKind::cube) {
    // The corners of the cube next to its even end that differ from it along one axis.
    Coord even{even_end(c[0], h), even_end(c[1], h), even_end(c[2], h)};
    for (int a = 0; a < 3; ++a) {
      Coord x = even;
      x[a] = odd_end(c[a], h);
      add(x);
    }
  } else if (d.kind == DiamondKind::face) {
    for (int sgn : {-1, 1}) {
      Coord x = c;
      x[d.axis] += sgn * h;
      add(x);
    }
  } else {
    for (int a = 0; a < 3; ++a) {
      if (a == d.axis) continue;
      for (int sgn : {-1, 1}) {
        Coord x = c;
        x[a] += sgn * h;
        add(x);
      }
    }
  }
  return n;
}

}  // namespace adaptiso::detail
