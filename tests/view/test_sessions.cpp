// The viewer's page sessions (src/view/sessions.hpp) without HTTP: clients kept by recency, one
// extractor per client and level, the follower's background surface, stale jobs dropped, and its
// extraction yielding to a page's request.
#include <gtest/gtest.h>

#include <memory>
#include <mutex>
#include <thread>

#include "adaptiso/extractor.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/synthetic.hpp"
#include "view/sessions.hpp"

using namespace adaptiso;
using detail::Sessions;

namespace {

std::shared_ptr<const PreparedGrid> sphere() {
  static const auto grid = [] {
    const Volume v = make_synthetic("sphere", 33, ScalarType::f32);
    PrepareOptions o;
    o.max_error = 0.02;
    o.relative = true;
    return std::make_shared<const PreparedGrid>(prepare(v, o));
  }();
  return grid;
}

double mid_iso(const PreparedGrid& g, double f = 0.5) { return g.grid.source.min + f * (g.grid.source.max - g.grid.source.min); }

// The mesh a fresh Extractor gives: what every session's surface must be.
Mesh fresh(const std::shared_ptr<const PreparedGrid>& g, double iso) {
  Extractor ex(g);
  ex.extract(iso);
  return ex.mesh();
}

void expect_same(const Mesh& a, const Mesh& b) {
  EXPECT_EQ(a.positions, b.positions);
  EXPECT_EQ(a.triangles, b.triangles);
}

}  // namespace

TEST(Sessions, KeepsTheMostRecentClients) {
  Sessions s(2);
  s.slot("a", 0);
  s.slot("b", 0);
  s.slot("a", 1);  // a is the most recent now
  s.slot("c", 0);  // b, the least recent, goes
  EXPECT_EQ(s.clients(), 2u);
  EXPECT_TRUE(s.has("a"));
  EXPECT_FALSE(s.has("b"));
  EXPECT_TRUE(s.has("c"));
  s.clear();
  EXPECT_EQ(s.clients(), 0u);
}

TEST(Sessions, EachClientAndLevelHasItsOwnExtractor) {
  Sessions s(8);
  const auto a0 = s.slot("a", 0);
  EXPECT_EQ(s.slot("a", 0), a0);
  EXPECT_NE(s.slot("a", 1), a0);
  EXPECT_NE(s.slot("b", 0), a0);
  // Two clients at different iso-values on the same grid each keep their own surface.
  const auto g = sphere();
  const double i1 = mid_iso(*g, 0.3), i2 = mid_iso(*g, 0.7);
  const auto b0 = s.slot("b", 0);
  {
    const auto lock = a0->lock_for_page(i1, g.get());
    expect_same(a0->at(g, i1), fresh(g, i1));
  }
  {
    const auto lock = b0->lock_for_page(i2, g.get());
    expect_same(b0->at(g, i2), fresh(g, i2));
  }
  EXPECT_EQ(a0->iso, i1);
  EXPECT_EQ(b0->iso, i2);
}

TEST(Sessions, ASlotStepsIncrementallyAndGivesTheFreshSurface) {
  Sessions s(8);
  const auto g = sphere();
  const auto slot = s.slot("a", 0);
  const auto lock = slot->lock_for_page(mid_iso(*g), g.get());
  ExtractStats first, second, again;
  slot->at(g, mid_iso(*g), &first);
  EXPECT_FALSE(first.incremental);
  const double next = mid_iso(*g, 0.501);
  const Mesh& stepped = slot->at(g, next, &second);
  EXPECT_TRUE(second.incremental);
  // The same surface as a fresh march's, its triangles in the order of the steps' making.
  const Mesh reference = fresh(g, next);
  EXPECT_EQ(stepped.triangle_count(), reference.triangle_count());
  EXPECT_EQ(stepped.vertex_count(), reference.vertex_count());
  slot->at(g, next, &again);  // the surface it holds: not extracted again, the same statistics
  EXPECT_EQ(again.triangles, second.triangles);
  EXPECT_EQ(again.incremental, second.incremental);
}

TEST(Sessions, TheFollowerExtractsTheSurfaceAtRest) {
  Sessions s(8);
  const auto g = sphere();
  const double iso = mid_iso(*g, 0.4);
  s.follow("a", 0, g, iso);
  s.follower().wait_idle();
  EXPECT_EQ(s.follower().completed(), 1u);
  const auto slot = s.slot("a", 0);
  EXPECT_EQ(slot->iso, iso);  // held before the page asks
  const auto lock = slot->lock_for_page(iso, g.get());
  expect_same(slot->at(g, iso), fresh(g, iso));
}

TEST(Sessions, AJobQueuedBeforeThePagesRequestIsDropped) {
  Sessions s(8);
  const auto g = sphere();
  const auto slot = s.slot("a", 0);
  {
    std::unique_lock hold(slot->mutex);  // the follower waits for the level
    s.follow("a", 0, g, mid_iso(*g, 0.4));
    slot->page_requests.fetch_add(1);  // a page asked for the level meanwhile
  }
  s.follower().wait_idle();
  EXPECT_EQ(s.follower().completed(), 0u);
  EXPECT_EQ(s.follower().cancelled(), 0u);
  EXPECT_FALSE(slot->extractor);  // nothing extracted for a stale iso-value
}

TEST(Sessions, TheFollowersExtractionYieldsToAPageAndLeavesNoSurface) {
  Sessions s(8);
  const auto g = sphere();
  const auto slot = s.slot("a", 0);
  const double iso = mid_iso(*g, 0.4);
  slot->page_waiting.store(true);  // a page waits for the level while the follower extracts
  s.follow("a", 0, g, iso);
  s.follower().wait_idle();
  EXPECT_EQ(s.follower().cancelled(), 1u);
  EXPECT_EQ(s.follower().completed(), 0u);
  EXPECT_NE(slot->iso, iso);  // no surface: the page's request extracts it afresh
  const auto lock = slot->lock_for_page(iso, g.get());
  EXPECT_FALSE(slot->page_waiting.load());
  expect_same(slot->at(g, iso), fresh(g, iso));
}

TEST(Sessions, APageAskingForTheSurfaceBeingFollowedDoesNotCancelIt) {
  Sessions s(8);
  const auto g = sphere();
  const auto slot = s.slot("a", 0);
  const double iso = mid_iso(*g, 0.6);
  // What lock_for_page sees while the follower extracts this very surface: no yield asked.
  slot->following.store(iso);
  slot->following_grid.store(g.get());
  {
    const auto lock = slot->lock_for_page(iso, g.get());
    EXPECT_FALSE(slot->page_waiting.load());
  }
  slot->following.store(mid_iso(*g, 0.1));  // another surface: the page asks it to yield
  std::unique_lock hold(slot->mutex);
  std::thread page([&] { const auto lock = slot->lock_for_page(iso, g.get()); });
  while (!slot->page_waiting.load()) std::this_thread::yield();
  hold.unlock();
  page.join();
  EXPECT_FALSE(slot->page_waiting.load());
}
