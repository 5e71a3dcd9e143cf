#pragma once
// A one-line progress bar on stderr with ETA, for long loops (training, import, simulation).
#include <chrono>
#include <cstdio>
#include <string>

namespace lidarsim {

class ProgressBar {
 public:
  ProgressBar(std::string label, long total, bool enabled = true);
  // Redraws at most ~10 times a second; `status` is appended (e.g. "loss 0.0123").
  void update(long done, const std::string& status = "");
  void finish(const std::string& status = "");

 private:
  std::string label_;
  long total_;
  bool enabled_;
  std::chrono::steady_clock::time_point start_, last_draw_;
  void draw(long done, const std::string& status);
};

std::string format_duration(double seconds);

}  // namespace lidarsim
