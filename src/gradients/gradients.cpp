// Vertex gradients — least squares over the 1-ring (Lürig & Ertl §2.3) or central differences of
// the volume — and the error of the tetrahedral grid's linear reconstruction at every original voxel.
//
// This work is based on:
// - Lürig, Ertl. Adaptive Iso-surface Generation. 1998. §2.3 (least squares over the 1-ring; the reconstruction
//   error of §2.1 measured on the grid).
#include "adaptiso/gradients.hpp"

#include "util/big_array.hpp"
#include "util/progress_counter.hpp"

#include <tbb/combinable.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <numeric>

namespace adaptiso {

VertexRings vertex_rings(const TetGrid& grid) {
  const std::size_t n = grid.vertex_count();
  VertexRings r;
  r.offsets.assign(n + 1, 0);
  // Count directed edge slots per vertex (with duplicates), fill, then sort and unique per vertex.
  for (const auto& t : grid.tets)
    for (int i = 0; i < 4; ++i) r.offsets[t[i] + 1] += 3;
  for (std::size_t i = 0; i < n; ++i) r.offsets[i + 1] += r.offsets[i];
  std::vector<std::uint32_t> nb(r.offsets[n]);
  std::vector<std::uint64_t> fill(r.offsets.begin(), r.offsets.end() - 1);
  for (const auto& t : grid.tets)
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        if (i != j) nb[fill[t[i]]++] = t[j];
  std::vector<std::uint64_t> counts(n);
  tbb::parallel_for(std::size_t{0}, n, [&](std::size_t v) {
    auto b = nb.begin() + static_cast<long>(r.offsets[v]), e = nb.begin() + static_cast<long>(r.offsets[v + 1]);
    std::sort(b, e);
    counts[v] = static_cast<std::uint64_t>(std::unique(b, e) - b);
  });
  r.neighbours.reserve(std::accumulate(counts.begin(), counts.end(), std::uint64_t{0}));
  std::vector<std::uint64_t> off(n + 1, 0);
  for (std::size_t v = 0; v < n; ++v) {
    r.neighbours.insert(r.neighbours.end(), nb.begin() + static_cast<long>(r.offsets[v]),
                        nb.begin() + static_cast<long>(r.offsets[v] + counts[v]));
    off[v + 1] = r.neighbours.size();
  }
  r.offsets = std::move(off);
  return r;
}

void least_squares_gradients(TetGrid& grid, const Progress& progress) {
  const VertexRings rings = vertex_rings(grid);
  const std::size_t n = grid.vertex_count();
  grid.gradients.assign(n, {0, 0, 0});
  detail::ProgressCounter done(progress, "gradients", n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024), [&](const tbb::blocked_range<std::size_t>& r) {
    Eigen::MatrixXd A;
    Eigen::VectorXd b;
    for (std::size_t v = r.begin(); v < r.end(); ++v) {
      const std::size_t k = static_cast<std::size_t>(rings.offsets[v + 1] - rings.offsets[v]) + 1;
      A.resize(static_cast<Eigen::Index>(k), 4);
      b.resize(static_cast<Eigen::Index>(k));
      const Vec3 pv = grid.position(static_cast<std::uint32_t>(v));
      // Centred at the vertex (better conditioned; a is then the fitted value at v).
      auto row = [&](Eigen::Index i, std::uint32_t u) {
        Vec3 p = grid.position(u);
        A.row(i) << 1.0, p[0] - pv[0], p[1] - pv[1], p[2] - pv[2];
        b(i) = grid.values[u] - grid.values[v];
      };
      row(0, static_cast<std::uint32_t>(v));
      for (std::uint64_t j = rings.offsets[v]; j < rings.offsets[v + 1]; ++j)
        row(static_cast<Eigen::Index>(j - rings.offsets[v] + 1), rings.neighbours[j]);
      Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinU | Eigen::ComputeThinV);
      svd.setThreshold(1e-9);  // relative to the largest singular value: drops undetermined directions
      Eigen::Vector4d x = svd.solve(b);
      grid.gradients[v] = {static_cast<float>(x(1)), static_cast<float>(x(2)), static_cast<float>(x(3))};
    }
    done.advance(r.size());
  });
}

void central_difference_gradients(TetGrid& grid, const Volume& vol, const Progress& progress) {
  const std::size_t n = grid.vertex_count();
  detail::resize_big(grid.gradients, n);
  // On a padded lattice (tet_grid.hpp) the volume's own box: its far faces take one-sided
  // differences as an unpadded grid's do, and a vertex in the padding the gradient of the voxel it
  // copies.
  Dims d = grid.source.volume_box();
  for (int a = 0; a < 3; ++a) d[a] = std::min(d[a], vol.dims[a]);
  const std::int64_t stride[3] = {1, vol.dims[0], vol.dims[0] * vol.dims[1]};
  visit_values(vol, [&]<class T>(std::span<const T> values) {
    const T* f = values.data();
    detail::ProgressCounter done(progress, "gradients", n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t v = r.begin(); v < r.end(); ++v) {
        std::array<std::int64_t, 3> p;
        for (int a = 0; a < 3; ++a) p[a] = std::min<std::int64_t>(grid.ijk[v][a], d[a] - 1);
        const std::int64_t i = vol.index(p[0], p[1], p[2]);
        std::array<float, 3> out{0, 0, 0};
        for (int a = 0; a < 3; ++a) {
          const std::int64_t c = p[a], s = stride[a];
          double diff = 0;
          if (d[a] == 1)
            diff = 0;  // one voxel thick: no variation along this axis is known
          else if (c == 0)
            diff = static_cast<double>(f[i + s]) - static_cast<double>(f[i]);
          else if (c == d[a] - 1)
            diff = static_cast<double>(f[i]) - static_cast<double>(f[i - s]);
          else
            diff = 0.5 * (static_cast<double>(f[i + s]) - static_cast<double>(f[i - s]));
          out[a] = static_cast<float>(diff / vol.spacing[a]);
        }
        grid.gradients[v] = out;
      }
      done.advance(r.size());
    });
  });
}

// The error at every voxel, measured in the tetrahedron that claims it first. The result must not
// depend on which one that is (thread timing decides; grid files and `run` outputs must be the same
// bytes for any thread count): a voxel on a shared face, edge or vertex has the same barycentric
// coordinates in every tetrahedron around it (the same rational numbers, each correctly rounded),
// and its terms are added in ascending vertex id, so its interpolant is the same double whichever
// tetrahedron claims it. The maximum is then order-free; the sum of squares is taken over the
// per-voxel errors in voxel order with a deterministic reduction.
ReconstructionError piecewise_linear_error(const Volume& vol, const TetGrid& grid, const Progress& progress) {
  const std::size_t nvox = static_cast<std::size_t>(vol.voxel_count());
  constexpr float unclaimed = -1.0f;
  std::vector<float> error;  // per voxel, < 0 until a tetrahedron claims it
  detail::assign_big(error, nvox, unclaimed);
  tbb::combinable<double> largest([] { return 0.0; });
  const std::size_t nt = grid.tet_count();
  detail::ProgressCounter done(progress, "reconstruction error", nt);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nt, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
    double& worst = largest.local();
    for (std::size_t t = r.begin(); t < r.end(); ++t) {
      const auto& T = grid.tets[t];
      std::int64_t P[4][3];
      std::int64_t lo[3], hi[3];
      for (int c = 0; c < 3; ++c) {
        lo[c] = INT64_MAX;
        hi[c] = INT64_MIN;
      }
      for (int i = 0; i < 4; ++i)
        for (int c = 0; c < 3; ++c) {
          P[i][c] = grid.ijk[T[i]][c];
          lo[c] = std::min(lo[c], P[i][c]);
          hi[c] = std::max(hi[c], P[i][c]);
        }
      // Corners in ascending vertex id: the order the interpolant adds its terms in.
      std::array<int, 4> order{0, 1, 2, 3};
      std::sort(order.begin(), order.end(), [&](int a, int b) { return T[a] < T[b]; });
      // Signed volumes in index space (exact in 64-bit integers).
      auto det = [](const std::int64_t* a, const std::int64_t* b, const std::int64_t* c, const std::int64_t* d) {
        std::int64_t u[3], v[3], w[3];
        for (int k = 0; k < 3; ++k) {
          u[k] = b[k] - a[k];
          v[k] = c[k] - a[k];
          w[k] = d[k] - a[k];
        }
        return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
      };
      const std::int64_t D = det(P[0], P[1], P[2], P[3]);
      if (D == 0) continue;
      for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
        for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
          for (std::int64_t x = lo[0]; x <= hi[0]; ++x) {
            const std::int64_t q[3] = {x, y, z};
            std::int64_t l[4] = {det(q, P[1], P[2], P[3]), det(P[0], q, P[2], P[3]), det(P[0], P[1], q, P[3]), det(P[0], P[1], P[2], q)};
            bool in = true;
            for (auto li : l) in = in && (D > 0 ? li >= 0 : li <= 0);
            if (!in) continue;
            const std::size_t idx = static_cast<std::size_t>(vol.index(x, y, z));
            if (std::atomic_ref<float>(error[idx]).load(std::memory_order_relaxed) >= 0) continue;
            double rec = 0;
            for (int i : order)
              if (l[i] != 0) rec += static_cast<double>(l[i]) / static_cast<double>(D) * grid.values[T[i]];
            const double e = std::abs(vol.at(static_cast<std::int64_t>(idx)) - rec);
            float expected = unclaimed;
            if (!std::atomic_ref<float>(error[idx]).compare_exchange_strong(expected, static_cast<float>(e), std::memory_order_relaxed))
              continue;
            worst = std::max(worst, e);
          }
    }
    done.advance(r.size());
  });
  struct Sum {
    double sq = 0;
    std::int64_t n = 0;
  };
  const Sum total = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, nvox, std::size_t{1} << 16), Sum{},
      [&](const tbb::blocked_range<std::size_t>& r, Sum s) {
        for (std::size_t i = r.begin(); i < r.end(); ++i)
          if (error[i] >= 0) {
            s.sq += static_cast<double>(error[i]) * static_cast<double>(error[i]);
            ++s.n;
          }
        return s;
      },
      [](Sum a, const Sum& b) {
        return Sum{a.sq + b.sq, a.n + b.n};
      });
  double max = 0;
  largest.combine_each([&](double m) { max = std::max(max, m); });
  return {max, total.n ? std::sqrt(total.sq / static_cast<double>(total.n)) : 0.0, total.n};
}

}  // namespace adaptiso
