// `mpirun -np N adaptiso view GRID.adg` (issue 38): rank 0 serves the page and the API as one
// process does, and the surfaces within a distance (the page's dragged and resting surfaces, and
// exports with distance=) are made by the other ranks, each holding the same grid's hierarchy,
// one surface a rank at a time. When every other rank is busy, rank 0 makes the surface itself,
// so a job of N ranks answers N surfaces at once. A surface is the one one process makes, byte
// for byte: the same query on the same grid, its arrays handed over as they are.
#pragma once
#include <memory>

#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/view_server.hpp"
#include "ranks.hpp"

namespace adaptiso::cli {

// Rank 0's side: hands queries to idle ranks (ViewOptions::distance_surfaces). Destroying it tells
// the other ranks to stop; the hook it gave must not be called after.
class RankSurfaces {
public:
  explicit RankSurfaces(Ranks& ranks);
  ~RankSurfaces();
  RankSurfaces(const RankSurfaces&) = delete;
  RankSurfaces& operator=(const RankSurfaces&) = delete;
  DistanceSurfaces hook();

private:
  struct State;
  std::shared_ptr<State> state_;
};

// The other ranks' side: answers rank 0's queries with `query` until rank 0 says stop.
void answer_distance_queries(Ranks& ranks, const HierarchyQuery& query);

}  // namespace adaptiso::cli
