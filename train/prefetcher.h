#pragma once
// Produces the items k = first, first + 1, ..., end - 1 of a sequence (a training step's batch, a
// validation frame) on a background thread, one item ahead of the consumer: reading the next
// step's frames overlaps the current step's computation. Two slots: the consumer holds the item
// next() returned until it asks for the following one, the thread fills the other.
//
// Shutdown: the destructor stops the thread and joins it (after Ctrl-C, or while an exception
// unwinds the consumer); it waits at most for the item being produced. An exception thrown while
// producing item k is rethrown by the next() that asks for item k, so errors arrive in order.
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <thread>

namespace lidarsim::train {

template <class Item>
class Prefetcher {
 public:
  using Produce = std::function<void(std::int64_t k, Item& out)>;

  // `background` false: next() produces on the caller's thread (same items, no overlap).
  Prefetcher(Produce produce, std::int64_t first, std::int64_t end, bool background = true)
      : produce_(std::move(produce)), next_(first), end_(end) {
    if (background && first < end) thread_ = std::thread([this, first] { run(first); });
  }
  ~Prefetcher() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  Prefetcher(const Prefetcher&) = delete;
  Prefetcher& operator=(const Prefetcher&) = delete;

  // The next item, in order; valid until the following call.
  Item& next() {
    if (next_ >= end_) throw std::out_of_range("Prefetcher: no item after the last one");
    const std::int64_t k = next_++;
    const int slot = static_cast<int>(k & 1);
    if (!thread_.joinable()) {
      produce_(k, slots_[slot]);
      return slots_[slot];
    }
    std::unique_lock<std::mutex> lock(mutex_);
    if (held_ >= 0) ready_[held_] = false;  // the previous item is free to be overwritten
    held_ = -1;
    changed_.notify_all();
    changed_.wait(lock, [&] { return ready_[slot] || (error_ && failed_at_ == k); });
    if (!ready_[slot]) std::rethrow_exception(error_);
    held_ = slot;
    return slots_[slot];
  }

 private:
  void run(std::int64_t first) {
    for (std::int64_t k = first; k < end_; ++k) {
      const int slot = static_cast<int>(k & 1);
      {
        std::unique_lock<std::mutex> lock(mutex_);
        changed_.wait(lock, [&] { return stop_ || !ready_[slot]; });
        if (stop_) return;
      }
      try {
        produce_(k, slots_[slot]);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex_);
        error_ = std::current_exception();
        failed_at_ = k;
        changed_.notify_all();
        return;
      }
      std::lock_guard<std::mutex> lock(mutex_);
      ready_[slot] = true;
      changed_.notify_all();
    }
  }

  Produce produce_;
  std::int64_t next_, end_;
  Item slots_[2];
  bool ready_[2] = {false, false};
  int held_ = -1;
  bool stop_ = false;
  std::exception_ptr error_;
  std::int64_t failed_at_ = -1;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::thread thread_;
};

}  // namespace lidarsim::train
