// ViewCache: each view loaded once while among the most recently used, the least recently used
// dropped first, a failed load cached as nothing, and threads sharing it get the same values.
#include "pipeline/core/view_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>
#include <thread>
#include <vector>

namespace ibmr {
namespace {

TEST(ViewCache, LoadsAViewOnceWhileItIsRecentlyUsed) {
  std::vector<std::string> loaded;
  ViewCache<std::string> cache(2, [&](const std::string& name) {
    loaded.push_back(name);
    return "maps of " + name;
  });
  EXPECT_EQ(*cache.Get("a"), "maps of a");
  EXPECT_EQ(*cache.Get("b"), "maps of b");
  EXPECT_EQ(*cache.Get("a"), "maps of a");  // hit; "a" is now the most recent
  EXPECT_EQ(*cache.Get("c"), "maps of c");  // drops "b", the least recently used
  EXPECT_EQ(*cache.Get("a"), "maps of a");  // still there
  EXPECT_EQ(*cache.Get("b"), "maps of b");  // loaded again
  EXPECT_EQ(loaded, (std::vector<std::string>{"a", "b", "c", "b"}));
  EXPECT_EQ(cache.Loads(), 4u);
  EXPECT_EQ(cache.Hits(), 2u);
}

TEST(ViewCache, AValueOutlivesItsEviction) {
  ViewCache<std::vector<int>> cache(1, [](const std::string& name) { return std::vector<int>(3, static_cast<int>(name.size())); });
  const auto first = cache.Get("one");
  cache.Get("three");  // evicts "one" from the cache, not from its holder
  EXPECT_EQ(*first, std::vector<int>(3, 3));
}

TEST(ViewCache, AFailedLoadReachesTheCallerAndIsNotCached) {
  int attempts = 0;
  ViewCache<int> cache(4, [&](const std::string& name) {
    ++attempts;
    if (name == "bad") throw std::runtime_error("bad.bin: truncated");
    return 7;
  });
  EXPECT_THROW(cache.Get("bad"), std::runtime_error);
  EXPECT_THROW(cache.Get("bad"), std::runtime_error);
  EXPECT_EQ(attempts, 2);
  EXPECT_EQ(*cache.Get("good"), 7);
}

TEST(ViewCache, ThreadsShareTheLoadedValues) {
  std::atomic<int> loads{0};
  ViewCache<int> cache(8, [&](const std::string& name) {
    ++loads;
    return static_cast<int>(name[0]);
  });
  std::vector<std::thread> threads;
  std::atomic<int> wrong{0};
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      for (int i = 0; i < 1000; ++i) {
        const std::string name(1, static_cast<char>('a' + i % 6));
        if (*cache.Get(name) != name[0]) ++wrong;
      }
    });
  }
  for (auto& thread : threads) thread.join();
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_LE(loads.load(), 6 * 4);  // at worst each thread loads each view once, never more
}

}  // namespace
}  // namespace ibmr
