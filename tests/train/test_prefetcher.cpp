// The prefetching thread: items in order, errors at their item, a prompt stop and join.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>

#include "train/prefetcher.h"

using lidarsim::train::Prefetcher;

TEST(Prefetcher, DeliversEveryItemInOrderWhileTheNextIsProducedAhead) {
  std::atomic<std::int64_t> produced{-1};
  Prefetcher<std::int64_t> p(
      [&](std::int64_t k, std::int64_t& out) {
        out = k * k;
        produced = k;
      },
      3, 9);
  for (std::int64_t k = 3; k < 9; ++k) {
    const std::int64_t value = p.next();
    EXPECT_EQ(value, k * k);
    if (k + 1 < 9) {  // the thread goes on to the next item while this one is in use
      const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
      while (produced.load() < k + 1 && std::chrono::steady_clock::now() < until) std::this_thread::yield();
      EXPECT_GE(produced.load(), k + 1);
    }
    EXPECT_LE(produced.load(), k + 1) << "ran more than one item ahead";
  }
  EXPECT_THROW(p.next(), std::out_of_range);
}

TEST(Prefetcher, AnErrorIsRethrownAtItsItemAfterTheItemsBeforeIt) {
  Prefetcher<int> p(
      [](std::int64_t k, int& out) {
        if (k == 2) throw std::runtime_error("frame 2 of f.h5 is damaged");
        out = static_cast<int>(k);
      },
      0, 5);
  EXPECT_EQ(p.next(), 0);
  EXPECT_EQ(p.next(), 1);
  try {
    p.next();
    FAIL() << "expected the producer's error";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "frame 2 of f.h5 is damaged");
  }
}

TEST(Prefetcher, StoppingEarlyJoinsPromptlyAndProducesNothingMore) {
  std::atomic<int> calls{0};
  const auto start = std::chrono::steady_clock::now();
  {
    Prefetcher<int> p([&](std::int64_t k, int& out) { out = static_cast<int>(k), ++calls; }, 0, 1000000);
    EXPECT_EQ(p.next(), 0);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));  // the thread fills its one free slot and waits
  }  // as after Ctrl-C: the loop leaves, the prefetcher is destroyed
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LE(calls.load(), 2);
  EXPECT_LT(seconds, 5.0);
}

TEST(Prefetcher, AnExceptionInTheConsumerUnwindsThroughItWithoutTerminating) {
  std::atomic<bool> producing{false};
  try {
    Prefetcher<int> p(
        [&](std::int64_t k, int& out) {
          producing = true;
          std::this_thread::sleep_for(std::chrono::milliseconds(k == 1 ? 100 : 0));  // busy when the consumer throws
          out = static_cast<int>(k);
        },
        0, 10);
    p.next();
    throw std::runtime_error("step failed");
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "step failed");
  }
  EXPECT_TRUE(producing.load());
}

TEST(Prefetcher, SynchronousModeProducesTheSameItemsOnTheCallersThread) {
  const auto caller = std::this_thread::get_id();
  Prefetcher<int> p(
      [&](std::int64_t k, int& out) {
        EXPECT_EQ(std::this_thread::get_id(), caller);
        out = static_cast<int>(2 * k);
      },
      0, 3, false);
  EXPECT_EQ(p.next(), 0);
  EXPECT_EQ(p.next(), 2);
  EXPECT_EQ(p.next(), 4);
}
