// A stage's progress counted from many threads reaches its listener in order (the grid check's
// walk once told 0.271 and then 0.235 on a loaded CI machine: two threads counted 27 and 28 of its
// subtrees and the second told first).
#include <gtest/gtest.h>

#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "util/progress_counter.hpp"

using namespace adaptiso;

TEST(ProgressCounter, FractionsCountedFromManyThreadsArriveInOrderAtMostOncePerStep) {
  for (const std::uint64_t steps : {1, 7, 100}) {
    std::mutex m;
    std::vector<std::pair<std::string, double>> seen;
    const Progress progress = [&](std::string_view stage, double f) {
      const std::lock_guard lock(m);
      seen.emplace_back(std::string(stage), f);
      std::this_thread::yield();  // a listener that takes its time widens the window a race needs
    };
    constexpr int kThreads = 8, kEach = 20000;
    detail::ProgressCounter counter(progress, "walk", std::uint64_t{kThreads} * kEach, 0.25, 0.75, steps);
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t)
      threads.emplace_back([&] {
        for (int i = 0; i < kEach; ++i) counter.advance(1);
      });
    for (auto& t : threads) t.join();
    ASSERT_FALSE(seen.empty());
    EXPECT_LE(seen.size(), steps);
    for (std::size_t i = 0; i < seen.size(); ++i) {
      EXPECT_EQ(seen[i].first, "walk");
      EXPECT_GT(seen[i].second, 0.25);
      EXPECT_LE(seen[i].second, 0.75);
      if (i) EXPECT_GT(seen[i].second, seen[i - 1].second) << "told " << seen[i - 1].second << " before " << seen[i].second;
    }
    EXPECT_EQ(seen.back().second, 0.75) << "the last count tells the stage's end";
  }
}

TEST(ProgressCounter, CountsPastTheTotalOrWithNoTotalOrNoListenerTellNothingWrong) {
  std::vector<double> seen;
  const Progress progress = [&](std::string_view, double f) { seen.push_back(f); };
  detail::ProgressCounter over(progress, "s", 10);
  over.advance(512);  // a coarse count larger than the whole (the reduction counts 512 at a time)
  over.advance(512);
  EXPECT_EQ(seen, std::vector<double>{1.0});
  seen.clear();
  detail::ProgressCounter none(progress, "s", 0);
  none.advance(5);
  EXPECT_TRUE(seen.empty());
  detail::ProgressCounter deaf(Progress{}, "s", 10);
  deaf.advance(10);  // no listener: nothing to call
}
