// Vertex gradients by least squares over the 1-ring — Lürig & Ertl §2.3 — and the error of the
// tetrahedral grid's linear reconstruction at every original voxel.
#include "adaptiso/gradients.hpp"

#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <Eigen/SVD>
#include <atomic>
#include <cmath>

namespace adaptiso {

void compute_gradients(TetGrid& g, const VertexRings& rings, const Progress& progress) {
  const std::size_t n = g.vertex_count();
  g.gradients.assign(n, {0, 0, 0});
  std::atomic<std::size_t> done{0};
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024), [&](const tbb::blocked_range<std::size_t>& r) {
    Eigen::MatrixXd A;
    Eigen::VectorXd b;
    for (std::size_t v = r.begin(); v < r.end(); ++v) {
      const std::size_t k = static_cast<std::size_t>(rings.offsets[v + 1] - rings.offsets[v]) + 1;
      A.resize(static_cast<Eigen::Index>(k), 4);
      b.resize(static_cast<Eigen::Index>(k));
      const Vec3 pv = g.position(static_cast<std::uint32_t>(v));
      // Centred at the vertex (better conditioned; a is then the fitted value at v).
      auto row = [&](Eigen::Index i, std::uint32_t u) {
        Vec3 p = g.position(u);
        A.row(i) << 1.0, p[0] - pv[0], p[1] - pv[1], p[2] - pv[2];
        b(i) = g.values[u] - g.values[v];
      };
      row(0, static_cast<std::uint32_t>(v));
      for (std::uint64_t j = rings.offsets[v]; j < rings.offsets[v + 1]; ++j)
        row(static_cast<Eigen::Index>(j - rings.offsets[v] + 1), rings.neighbours[j]);
      Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinU | Eigen::ComputeThinV);
      svd.setThreshold(1e-9);  // relative to the largest singular value: drops undetermined directions
      Eigen::Vector4d x = svd.solve(b);
      g.gradients[v] = {static_cast<float>(x(1)), static_cast<float>(x(2)), static_cast<float>(x(3))};
    }
    std::size_t d = done += r.size();
    report(progress, "gradients", static_cast<double>(d) / static_cast<double>(n));
  });
}

ReconstructionError piecewise_linear_error(const Volume& vol, const TetGrid& g, const Progress& progress) {
  const std::size_t nvox = static_cast<std::size_t>(vol.voxel_count());
  std::vector<std::uint8_t> claimed(nvox, 0);
  struct Acc {
    double max = 0, sq = 0;
    std::int64_t n = 0;
  };
  tbb::combinable<Acc> acc;
  std::atomic<std::size_t> done{0};
  const std::size_t nt = g.tet_count();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nt, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
    Acc& a = acc.local();
    for (std::size_t t = r.begin(); t < r.end(); ++t) {
      const auto& T = g.tets[t];
      std::int64_t P[4][3];
      std::int64_t lo[3], hi[3];
      for (int c = 0; c < 3; ++c) {
        lo[c] = INT64_MAX;
        hi[c] = INT64_MIN;
      }
      for (int i = 0; i < 4; ++i)
        for (int c = 0; c < 3; ++c) {
          P[i][c] = g.ijk[T[i]][c];
          lo[c] = std::min(lo[c], P[i][c]);
          hi[c] = std::max(hi[c], P[i][c]);
        }
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
            if (std::atomic_ref<std::uint8_t>(claimed[idx]).exchange(1) != 0) continue;
            double rec = 0;
            for (int i = 0; i < 4; ++i) rec += static_cast<double>(l[i]) / static_cast<double>(D) * g.values[T[i]];
            double e = std::abs(vol.at(static_cast<std::int64_t>(idx)) - rec);
            a.max = std::max(a.max, e);
            a.sq += e * e;
            a.n++;
          }
    }
    std::size_t d = done += r.size();
    report(progress, "reconstruction error", static_cast<double>(d) / static_cast<double>(nt));
  });
  Acc total;
  acc.combine_each([&](const Acc& a) {
    total.max = std::max(total.max, a.max);
    total.sq += a.sq;
    total.n += a.n;
  });
  return {total.max, total.n ? std::sqrt(total.sq / static_cast<double>(total.n)) : 0.0, total.n};
}

}  // namespace adaptiso
