#include "infer/frame_writer.h"

#include <time.h>

#include <algorithm>

namespace lidarsim::infer {

FrameWriter::FrameWriter(SimOutputOptions options, int queue_frames)
    : options_(std::move(options)), capacity_(static_cast<std::size_t>(std::max(1, queue_frames))) {
  thread_ = std::thread([this] { run(); });
}

FrameWriter::~FrameWriter() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  changed_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void FrameWriter::push(const SimFrame& frame) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] { return queue_.size() < capacity_ || error_; });
  if (error_) std::rethrow_exception(error_);
  if (!spare_.empty()) {
    queue_.push_back(std::move(spare_.back()));
    spare_.pop_back();
    queue_.back() = frame;  // copy-assign into reused buffers
  } else {
    queue_.push_back(frame);
  }
  lock.unlock();
  changed_.notify_all();
}

double FrameWriter::finish() {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] { return (queue_.empty() && !busy_) || error_; });
  if (error_) std::rethrow_exception(error_);
  double total = 0;
  for (double ms : frame_ms_) total += ms;
  return total;
}

void FrameWriter::run() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    changed_.wait(lock, [&] { return stop_ || !queue_.empty(); });
    if (queue_.empty()) return;  // stopped and drained
    SimFrame frame = std::move(queue_.front());
    queue_.pop_front();
    busy_ = true;
    lock.unlock();
    changed_.notify_all();
    double ms = 0;
    std::exception_ptr error;
    auto thread_cpu_ms = [] {
      timespec ts{};
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
      return 1e3 * ts.tv_sec + 1e-6 * ts.tv_nsec;
    };
    const double cpu0 = thread_cpu_ms();
    try {
      ms = write_frame_outputs(options_, frame);
    } catch (...) {
      error = std::current_exception();
    }
    const double cpu_ms = thread_cpu_ms() - cpu0;
    lock.lock();
    busy_ = false;
    frame_ms_.push_back(ms);
    frame_cpu_ms_.push_back(cpu_ms);
    if (error && !error_) error_ = error;
    spare_.push_back(std::move(frame));
    changed_.notify_all();
  }
}

}  // namespace lidarsim::infer
