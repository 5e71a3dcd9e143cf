#pragma once
// Frame outputs off the simulation's critical path: frames are copied into a short queue and a
// background thread writes them (write_frame_outputs), so the pipeline computes frame k+1 while
// frame k is being encoded as PNG/PCD. The queue is bounded: when outputs are slower than the
// pipeline, push() waits rather than let memory grow (lidar-infer sim --every N thins them).
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <thread>

#include "infer/sim_outputs.h"

namespace lidarsim::infer {

class FrameWriter {
 public:
  explicit FrameWriter(SimOutputOptions options, int queue_frames = 2);
  ~FrameWriter();  // finishes the queue (errors then are dropped: call finish() to see them)
  FrameWriter(const FrameWriter&) = delete;
  FrameWriter& operator=(const FrameWriter&) = delete;

  // Queues a copy of `frame`; rethrows the first error the writer met.
  void push(const SimFrame& frame);
  // Waits until every queued frame is written; rethrows the first error. Returns the total
  // milliseconds the writer spent writing.
  double finish();
  // Milliseconds the writer spent on each frame, in order of push(): wall clock, and the writer
  // thread's CPU time (what the outputs cost without waiting for a core). Read after finish().
  const std::vector<double>& frame_ms() const { return frame_ms_; }
  const std::vector<double>& frame_cpu_ms() const { return frame_cpu_ms_; }

 private:
  void run();
  SimOutputOptions options_;
  std::size_t capacity_;
  std::deque<SimFrame> queue_;
  std::vector<SimFrame> spare_;  // written frames, reused to avoid reallocating buffers
  std::mutex mutex_;
  std::condition_variable changed_;
  bool stop_ = false, busy_ = false;
  std::exception_ptr error_;
  std::vector<double> frame_ms_, frame_cpu_ms_;
  std::thread thread_;
};

}  // namespace lidarsim::infer
